"""The build benchmark's inputs to ocnn: snapped so that float32 key arithmetic is exact."""

import numpy as np

from bench.octree_build import SNAP, ocnn_inputs, snapped_cube


def _float32_voxels(x32: np.ndarray, depth: int) -> np.ndarray:
    """ocnn's key arithmetic: floor((x + 1) * 2^(depth-1)) computed in float32."""
    return np.floor((x32 + np.float32(1.0)) * np.float32(2 ** (depth - 1))).astype(np.int64)


def test_snapped_inputs_put_every_point_in_the_same_octant_in_float32_and_float64():
    rng = np.random.default_rng(0)
    depth = 8
    # points within 1e-9 of octant boundaries, where float32 rounding decides otherwise
    edges = rng.integers(1, 2 ** depth, size=(20000, 3)) / 2 ** depth
    pts = edges + rng.uniform(-1e-9, 1e-9, edges.shape)
    pts = np.vstack([pts, [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])      # the bounding box ends
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    cube = snapped_cube(pts)
    assert np.abs(cube - np.round(cube / SNAP) * SNAP).max() == 0
    xyz, _ = ocnn_inputs(pts, normals)
    x32 = xyz.numpy()
    assert np.array_equal(x32.astype(np.float64), (cube - 0.5) * 2.0)       # exact in float32
    ours = np.clip(np.floor(cube * 2 ** depth).astype(np.int64), 0, 2 ** depth - 1)
    theirs = np.clip(_float32_voxels(x32, depth), 0, 2 ** depth - 1)
    assert np.array_equal(ours, theirs)
    # without snapping, float32 arithmetic moves some of these points across a boundary
    from model.octree.pointcloud import normalization_of
    unsnapped = normalization_of(pts).to_cube(pts)
    u32 = ((unsnapped - 0.5) * 2.0).astype(np.float32)
    exact = np.clip(np.floor(unsnapped * 2 ** depth).astype(np.int64), 0, 2 ** depth - 1)
    assert (np.clip(_float32_voxels(u32, depth), 0, 2 ** depth - 1) != exact).any()


def test_label_change_check_measures_a_patch_against_dense_samples():
    """bench.octree_label_changes: the dense Hausdorff distance of a flat patch is the offset of
    the samples from it, and the previous probe rule gives the zero-length closing edge back."""
    from bench.octree_label_changes import closing_edge_unprobed, dense_hausdorff
    from model.octree import build_octree, patch_error
    from model.octree.geometry import cube_polygons

    rng = np.random.default_rng(3)
    pts = np.column_stack([rng.random((40_000, 2)), np.full(40_000, 0.53)])  # the plane z = 0.53
    pts = np.vstack([pts, [[0, 0, 0], [1, 1, 1]]])                           # the cube's extent
    octree = build_octree((pts, np.tile([0.0, 0.0, 1.0], (len(pts), 1))), 5, neighbors=False)
    lv = octree.levels[4]
    interior = (lv.npoints > 100) & np.all(np.abs(lv.centers()[:, :2] - 0.5) < 0.3, axis=1)
    node = int(np.flatnonzero(interior)[0])
    dense = octree.normalizations[0].to_cube(
        np.column_stack([rng.random((400_000, 2)), np.full(400_000, 0.53)]))
    # ~0 (the dense samples' own gaps, at most a few thousandths of the octant at its corners)
    assert dense_hausdorff(octree, 4, node, dense) < 0.1 * lv.size
    lifted = dense + [0.0, 0.0, 0.3 * lv.size]
    assert 0.3 * lv.size <= dense_hausdorff(octree, 4, node, lifted) < 0.4 * lv.size

    n = np.array([[0.3, 0.2, 0.93]]) / np.linalg.norm([0.3, 0.2, 0.93])
    verts, count = cube_polygons(n, np.zeros(1), 1.0)
    assert count[0] < 6
    with closing_edge_unprobed():
        probes = patch_error.patch_probes(n, np.zeros(1), verts, count, 1.0, 0.1)
    last = np.linalg.norm(probes.edge_b - probes.edge_a, axis=1)
    assert last[-1] == 0 and np.all(last[:-1] > 0)


def test_another_checkout_loads_beside_this_one():
    """bench.octree_versions imports another checkout's model.octree without replacing ours."""
    import os

    import model.octree as ours
    from bench.octree_versions import load_other

    from .conftest import sphere_points

    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    other = load_other(root)
    assert other is not ours and other.build_octree is not ours.build_octree
    import model.octree as again
    assert again is ours                                  # ours is back in place
    cloud = sphere_points(5_000, seed=2)
    a, b = ours.build_octree(cloud, 5), other.build_octree(cloud, 5)
    assert all(np.array_equal(x.label, y.label) for x, y in zip(a.levels, b.levels))
