"""ICP recovers a known rigid transform of a real shape's points."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from model.data.shapes import generate
from model.octree.metrics import chamfer_distance
from research.align import icp, rigid_fit


def test_rigid_fit_is_exact_and_never_a_reflection():
    rng = np.random.default_rng(1)
    p = rng.normal(size=(50, 3))
    rot = Rotation.from_rotvec([0.3, -1.2, 0.5]).as_matrix()
    r, t = rigid_fit(p, p @ rot.T + [1, 2, 3])
    assert np.allclose(r, rot) and np.allclose(t, [1, 2, 3])
    mirrored = p * [-1, 1, 1]
    r, _ = rigid_fit(p, mirrored)
    assert np.linalg.det(r) == pytest.approx(1.0)


@pytest.mark.parametrize("category", ["chair", "car", "airplane"])
def test_icp_recovers_a_known_transform_of_a_sampled_shape(category):
    mesh = generate(category, 3)
    rng = np.random.default_rng(0)
    truth = mesh.sample(6000, seed=1)
    pred = mesh.sample(3000, seed=2) + rng.normal(0, 0.002, (3000, 3))     # other samples, noisy
    rot = Rotation.from_euler("xyz", [6, -4, 8], degrees=True).as_matrix()
    moved = (pred - 0.5) @ rot.T + 0.5 + [0.02, -0.03, 0.01]
    a = icp(moved, truth)
    back = a.apply(moved)
    assert np.abs(a.rotation @ rot - np.eye(3)).max() < 0.02
    assert chamfer_distance(truth, back) < 0.3 * chamfer_distance(truth, moved)
    assert chamfer_distance(truth, back) < 2 * chamfer_distance(truth, pred) + 1e-6


def test_icp_rejects_too_few_points():
    with pytest.raises(ValueError, match="at least 3"):
        icp(np.zeros((2, 3)), np.zeros((10, 3)))


def test_icp_composes_its_steps_as_kabsch_fits_applied_in_order():
    """Four iterations (no early stop) equal four nearest-neighbour Kabsch fits composed by hand:
    the transform is the last fit after the earlier ones, ``r4 r3 r2 r1``; rotations do not
    commute, so another order lands elsewhere."""
    from scipy.spatial import cKDTree

    mesh = generate("chair", 1)
    target = mesh.sample(3000, seed=1)
    rot = Rotation.from_euler("xyz", [25, -15, 20], degrees=True).as_matrix()
    source = mesh.sample(1500, seed=2) @ rot.T + [0.05, -0.02, 0.03]
    a = icp(source, target, iterations=4, tolerance=-1.0)
    tree, moved, total = cKDTree(target), source.copy(), np.eye(3)
    for _ in range(4):
        _, idx = tree.query(moved)
        r, t = rigid_fit(moved, target[idx])
        moved, total = moved @ r.T + t, r @ total
    assert a.iterations == 4
    assert np.allclose(a.apply(source), moved, atol=1e-9)
    assert np.allclose(a.rotation, total, atol=1e-12)
