"""Mirror symmetry of partial scans: the plane is found wherever the scan sits, asymmetric scans
are left as they are, and the mirror image fills the side the scanner missed."""

import numpy as np
import pytest
import trimesh

from model.data.shapes import generate
from model.octree import PointCloud, validate
from model.octree.metrics import mean_squared_distance, missing_part
from model.octree.symmetry import (
    MIN_SUPPORT,
    SHEET,
    TOLERANCE,
    Mirror,
    _coarse_supports,
    _dilate,
    find_mirror,
    is_sheet,
    mirror_cloud,
    symmetrize,
)

from .conftest import mesh_points

SHIFT = np.array([3.7, -1.2, 0.4])     # the user's frame: the plane is not at x = 0


@pytest.fixture(scope="module")
def chair():
    """A procedural chair (mirror-symmetric about x = 0 by construction) sampled with normals, moved
    to SHIFT and scaled by 2.5."""
    pts, nrm = mesh_points(generate("chair", 3), 30_000)
    return pts * 2.5 + SHIFT, nrm


def seen_part(pts: np.ndarray, right: float, up: float) -> np.ndarray:
    """A partial scan as the scanner's views leave them: the part of the right side beyond
    ``right`` and above ``up`` (shares of the extent from the middle) never seen, nor a band of
    the left side's lower half."""
    x, y = pts[:, 0] - SHIFT[0], pts[:, 1] - np.median(pts[:, 1])
    return ~((x > right * np.ptp(x)) & (y > up * np.ptp(y))) & ~((x < -0.15 * np.ptp(x)) & (y < 0) & (y > -0.1 * np.ptp(y)))


@pytest.mark.parametrize("right, up", [(0.0, 0.0), (0.1, 0.2), (0.3, 0.3)])
def test_the_plane_of_a_symmetric_object_is_found_from_a_part_of_it(chair, right, up):
    pts, _ = chair
    seen = seen_part(pts, right, up)
    m = find_mirror(pts[seen])
    extent = np.ptp(pts, 0).max()
    assert m.axis == 0 and abs(m.offset - SHIFT[0]) < 0.002 * extent
    assert 0.5 < m.support < 0.95                           # what is missing has no image on the scan
    assert find_mirror(pts[seen]) == m                      # deterministic
    whole = find_mirror(pts)
    assert abs(whole.offset - SHIFT[0]) < 0.002 * extent and whole.support > 0.95


@pytest.mark.parametrize("right, up", [(0.0, 0.0), (0.3, 0.3), (1.0, 1.0)])
def test_the_shortlisted_search_finds_the_plane_the_exhaustive_one_finds(chair, right, up):
    """The voxel scoring only shortlists candidates: the plane and its support are those of the
    reference search, which measures every candidate exactly (right = up = 1: the whole chair)."""
    pts, _ = chair
    part = pts[seen_part(pts, right, up)]
    fast, ref = find_mirror(part), find_mirror(part, shortlist=None)
    assert abs(fast.offset - ref.offset) < 1e-4 * np.ptp(pts, 0).max()
    assert abs(fast.support - ref.support) < 1e-3


def test_the_voxel_scores_peak_at_the_plane(chair):
    pts, _ = chair
    part = pts[seen_part(pts, 0.1, 0.2)]
    lo, hi = part.min(0), part.max(0)
    offsets = np.linspace(lo[0], hi[0], 81)
    tol = 0.01 * np.linalg.norm(hi - lo)
    scores = _coarse_supports(part, part[::10], 0, offsets, tol)
    assert scores.shape == (81,) and np.all((scores >= 0) & (scores <= 1))
    assert abs(offsets[np.argmax(scores)] - SHIFT[0]) <= offsets[1] - offsets[0]
    exact = find_mirror(part, shortlist=None).support
    assert abs(scores.max() - exact) < 0.1 and np.median(scores) < 0.5 * exact      # a peak, not a plateau


def test_the_mirror_image_fills_the_side_the_scanner_missed(chair):
    pts, nrm = chair
    seen = seen_part(pts, 0.4, 0.4)
    cloud = validate(pts[seen], nrm[seen])
    out, m = symmetrize(cloud)
    assert m.support >= MIN_SUPPORT and m.supported()
    assert len(out) == 2 * len(cloud) and np.array_equal(out.points[:len(cloud)], cloud.points)
    missing = missing_part(pts, cloud.points, 0.02 * np.ptp(pts, 0).max())
    assert len(missing) > 0.05 * len(pts)                    # the right side's top was not scanned
    before = mean_squared_distance(missing, cloud.points)
    after = mean_squared_distance(missing, out.points)
    assert after < 0.05 * before                             # the mirror image covers it
    mirrored = out.normals[len(cloud):]
    assert np.allclose(mirrored[:, 0], -cloud.normals[:, 0]) and np.allclose(mirrored[:, 1:], cloud.normals[:, 1:])
    twice = m.reflect(m.reflect(cloud.points))
    assert np.allclose(twice, cloud.points)


def test_an_asymmetric_scan_is_left_as_it_is():
    """An L of two boxes: no plane across x maps most of it onto itself."""
    body = trimesh.creation.box([1.0, 0.5, 0.5])
    arm = trimesh.creation.box([0.3, 0.5, 1.2])
    arm.apply_translation([0.35, 0.0, 0.85])
    pts, nrm = mesh_points(trimesh.util.concatenate([body, arm]), 20_000)
    cloud = validate(pts, nrm)
    out, m = symmetrize(cloud)
    assert m.support < MIN_SUPPORT and not m.supported()
    assert out is cloud


def _relief(thickness: float, seed: int = 0) -> np.ndarray:
    """A long strip in the xy plane (a relief of an animal, say), a head at one end only, its
    surface sampled and scanned with the training scans' noise (0.5% of its size); ``thickness``
    (share of its length): 0 for a sheet, else the strip is a solid slab that thick."""
    parts = [trimesh.creation.box([1.0, 0.16, max(thickness, 1e-4)])]
    head = trimesh.creation.box([0.12, 0.26, max(thickness, 1e-4)])
    head.apply_translation([0.44, 0.0, 0.0])
    parts.append(head)
    pts, nrm = mesh_points(trimesh.util.concatenate(parts), 20_000, seed=seed)
    if thickness == 0:
        keep = nrm[:, 2] > 0.9                     # one face, as a flat mesh has: the scanner saw it
        pts = pts[keep]
    rng = np.random.default_rng(seed)
    return pts + rng.normal(0, 0.005, pts.shape) + SHIFT


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_sheet_is_never_mirrored_however_symmetric_its_outline(seed):
    """A flat relief's mirror image lands on it in depth whatever its outline: its support passes
    (the head at one end is a small part of the strip), but it is a sheet and is left as scanned.
    The same outline as a solid slab a tenth as thick as it is long is mirrored."""
    flat = _relief(0.0, seed)
    m = find_mirror(flat)
    assert m.support >= MIN_SUPPORT and m.sheet and not m.supported()
    cloud = validate(flat, np.tile([0.0, 0.0, 1.0], (len(flat), 1)))
    out, same = symmetrize(cloud)
    assert out is cloud and same == m
    solid = find_mirror(_relief(0.1, seed))
    assert not solid.sheet and solid.supported()


@pytest.mark.parametrize("category", ["airplane", "display", "rifle", "telephone"])
def test_generated_flat_shapes_are_not_sheets(category):
    """The generated categories nearest a sheet (wings, screens, thin stocks) are solids: 95% of a
    noisy sample lies beyond 1.5 tolerances of their best-fit plane."""
    rng = np.random.default_rng(0)
    for index in range(4):
        pts, _ = mesh_points(generate(category, index), 20_000)
        tol = TOLERANCE * np.linalg.norm(np.ptp(pts, 0))
        assert not is_sheet(pts + rng.normal(0, 0.005 * np.ptp(pts, 0).max(), pts.shape), tol)


def test_is_sheet_at_its_band():
    """Points uniform in a slab of half-thickness h: 95% within 0.95 h of the mid-plane."""
    rng = np.random.default_rng(0)
    pts = rng.uniform([-1, -1, -0.01], [1, 1, 0.01], (20_000, 3))
    assert is_sheet(pts, 0.0095 / SHEET * 1.01) and not is_sheet(pts, 0.0095 / SHEET * 0.99)
    assert is_sheet(pts @ np.linalg.qr(rng.normal(size=(3, 3)))[0], 0.0095 / SHEET * 1.01)    # any orientation


def test_bad_points_are_refused_and_degenerate_ones_have_no_support():
    with pytest.raises(ValueError, match=r"\(N, 3\)"):
        find_mirror(np.zeros((10, 2)))
    with pytest.raises(ValueError, match="N >= 3"):
        find_mirror(np.zeros((2, 3)))
    assert find_mirror(np.ones((5, 3))).support == 0.0


def test_mirror_cloud_of_a_given_plane():
    cloud = PointCloud(np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]]))
    out = mirror_cloud(cloud, Mirror(0, 2.0, 1.0))
    assert np.allclose(out.points[2:], [[3.0, 2.0, 3.0], [0.0, 5.0, 6.0]])
    assert np.allclose(out.normals[2:], [[-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])


def test_the_voxel_scores_are_the_numpy_formulation_s(chair):
    """The compiled count of mirror images landing in occupied cells equals the NumPy gather it
    replaced, candidate by candidate."""
    pts, _ = chair
    part = pts[seen_part(pts, 0.3, 0.5)]
    lo, hi = part.min(0), part.max(0)
    offsets = np.linspace(lo[0], hi[0], 81)
    tol = 0.01 * np.linalg.norm(hi - lo)
    sample = part[::7]
    other = [1, 2]
    step, bins = float(offsets[1] - offsets[0]), len(offsets)

    def cells(p):
        i = np.minimum(((p[:, 0] - lo[0]) / step).astype(np.int64), bins - 1)
        jk = ((p[:, other] - lo[other]) / tol).astype(np.int64)
        return i, jk[:, 0], jk[:, 1]

    i, j, k = cells(part)
    grid = np.zeros((3 * bins, j.max() + 1, k.max() + 1), bool)
    grid[i + bins, j, k] = True
    grid = _dilate(grid, (int(np.ceil(tol / step)), 1, 1))
    si, sj, sk = cells(sample)
    across = np.minimum(sj, grid.shape[1] - 1) * grid.shape[2] + np.minimum(sk, grid.shape[2] - 1)
    mirrored = 2 * np.arange(bins)[:, None] - si[None] - 1 + bins
    hit = np.take(grid.reshape(-1), mirrored * (grid.shape[1] * grid.shape[2]) + across[None])
    off_plane = np.abs(sample[None, :, 0] - offsets[:, None]) > 2 * tol
    counted = off_plane.sum(1)
    want = np.where(counted > 0, (hit & off_plane).sum(1) / np.maximum(counted, 1), 0.0)
    got = _coarse_supports(part, sample, 0, offsets, tol)
    assert np.array_equal(got, want) and want.max() > 0.5


def test_a_scan_laid_out_before_its_normals_builds_the_same_octree(chair):
    """The service finds a scan's mirror plane and places its points (mirrored when the plane is
    supported) beside the normals' estimation (:func:`lay_out_scan`): the same plane and octree as
    symmetrize then scan_octree, for a mirrored chair, an unmirrored L and with symmetry off; a
    plane across another axis is refused."""
    from model.octree.scan import lay_out_scan, scan_octree

    from .test_build import assert_same_octree

    body, arm = trimesh.creation.box([1.0, 0.5, 0.5]), trimesh.creation.box([0.3, 0.5, 1.2])
    arm.apply_translation([0.35, 0.0, 0.85])
    pts, _ = chair
    scans = {"chair": pts[seen_part(pts, 0.45, 0.4)][::3],       # a band of one side missing: mirrored
             "L": mesh_points(trimesh.util.concatenate([body, arm]), 8000)[0]}
    for name, points in scans.items():
        cloud = validate(points, None)
        for symmetry in (True, False):
            layout = lay_out_scan(cloud.points, 6, symmetry=symmetry)
            if symmetry:
                want, mirror = symmetrize(cloud)
                got, found = symmetrize(cloud, mirror=layout.mirror)
                assert found == mirror == layout.mirror and mirror.supported() == (name == "chair")
            else:
                want = got = cloud
                assert layout.mirror is None
            assert_same_octree(scan_octree(got, 6, placement=layout.placement), scan_octree(want, 6))
    with pytest.raises(ValueError, match="across axis 0, not 1"):
        symmetrize(cloud, axis=1, mirror=layout.mirror or find_mirror(cloud.points))
