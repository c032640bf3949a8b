"""The fast adaptive build decides every octant as the plain formulation does, and measures the
same delta_O: the probes it settles on the patch grid are exactly those the k-d tree would read
as zero, and the moments it sums faster are the same numbers."""

import numpy as np
import pytest
import trimesh

import model.octree.build as build_module
from model.octree import build_octree
from model.octree.segments import segment_sums

from .conftest import MESH_FILES, mesh_path, mesh_points, sphere_points
from .reference_error import reference_patch_errors

TOLERANCE = 1e-9
"""Largest difference allowed between the two delta_O values of a node (cube units)."""


def reference_build(cloud, depth, **kwargs):
    original = build_module.patch_errors
    build_module.patch_errors = reference_patch_errors
    try:
        return build_octree(cloud, depth, neighbors=False, **kwargs)
    finally:
        build_module.patch_errors = original


def assert_same(fast, ref):
    """Same nodes and labels at every depth; delta_O equal where measured (inf where inf)."""
    assert fast.nodes_per_depth() == ref.nodes_per_depth()
    for a, b in zip(fast.levels, ref.levels):
        assert np.array_equal(a.label, b.label), f"depth {a.depth}: {np.sum(a.label != b.label)} labels differ"
        assert np.array_equal(np.isnan(a.error), np.isnan(b.error))
        assert np.array_equal(np.isinf(a.error), np.isinf(b.error))
        both = np.isfinite(a.error)
        assert np.abs(a.error[both].astype(float) - b.error[both]).max(initial=0.0) <= TOLERANCE


def holey_sphere(n, seed):
    """A sphere with 40 random round holes of random sizes and a sparse band: every probe path
    (covered on the grid, settled by the k-d tree, farther than the bound) is taken."""
    rng = np.random.default_rng(seed)
    pts, nrm = sphere_points(n, seed=seed)
    centres = rng.normal(size=(40, 3))
    centres /= np.linalg.norm(centres, axis=1, keepdims=True)
    radii = rng.uniform(0.01, 0.12, 40)
    hole = ((pts[:, None] - centres[None]) ** 2).sum(2) < radii[None] ** 2
    keep = ~hole.any(1) & ~((np.abs(pts[:, 2]) < 0.1) & (rng.random(n) < 0.8))
    return pts[keep], nrm[keep]


def cabinet_points(n, seed=0):
    from model.data.shapes import generate
    return mesh_points(generate("cabinet", 2), n, seed=seed)


@pytest.mark.parametrize("make, depth", [
    # samples about one voxel apart: the grid tests' bounds are close to the tolerance here
    (lambda: sphere_points(25_000, seed=1), 6),
    (lambda: holey_sphere(25_000, seed=2), 6),
    (lambda: cabinet_points(40_000), 6),
    # sparse (cells merged 4x) and dense (cells split 4x) against the probe spacing
    (lambda: holey_sphere(8_000, seed=4), 8),
    (lambda: sphere_points(120_000, seed=2), 6),
    (lambda: sphere_points(40_000, seed=1), 7),
    (lambda: holey_sphere(60_000, seed=2), 7),
    (lambda: holey_sphere(20_000, seed=3), 8),
    (lambda: cabinet_points(50_000), 8),
    (lambda: mesh_points(trimesh.creation.box(extents=(1.0, 0.3, 0.7)), 30_000, seed=4), 6),
])
def test_fast_build_matches_the_plain_formulation_on_generated_shapes(make, depth):
    cloud = make()
    fast = build_octree(cloud, depth)
    assert_same(fast, reference_build(cloud, depth))
    # the grid-settled probes are not a different answer, only a shortcut
    assert_same(fast, build_octree(cloud, depth, probe_search=False))


def test_fast_build_matches_with_leaf_measurement_and_other_settings():
    cloud = holey_sphere(30_000, seed=5)
    kwargs = dict(measure_leaves=True, threshold=2.0, adaptive_depth=3, full_depth=1)
    assert_same(build_octree(cloud, 7, **kwargs), reference_build(cloud, 7, **kwargs))


@pytest.mark.parametrize("name", MESH_FILES)
def test_fast_build_matches_the_plain_formulation_on_every_test_mesh(name):
    mesh = trimesh.load(mesh_path(name), force="mesh")
    cloud = mesh_points(mesh, 30_000, seed=0)
    for depth in (6, 7, 8):
        assert_same(build_octree(cloud, depth), reference_build(cloud, depth))


def test_segment_sums_equal_reduceat_bit_for_bit():
    rng = np.random.default_rng(0)
    # short runs (one by one), up to 128 (eight running sums) and beyond (halves, recursively)
    lengths = np.concatenate([rng.integers(1, 9, 3000), rng.integers(9, 40, 50), rng.integers(100, 3000, 20),
                              [1, 8, 9, 100, 128, 129, 130, 136, 137, 257, 1000, 5000]])
    rng.shuffle(lengths)
    starts = np.cumsum(lengths) - lengths
    new = np.zeros(lengths.sum(), dtype=bool)
    new[starts] = True
    rows = rng.normal(size=(12, len(new))) * rng.uniform(1e-3, 1e3, (12, 1))
    rows[:, rng.random(len(new)) < 0.05] = -0.0              # signed zeros, in runs of one too
    rows[2] = np.where(rows[2] > 0, 0.0, -0.0)
    got, want = segment_sums(rows, new, len(starts)), np.add.reduceat(rows, starts, axis=1)
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))


def test_boundary_probes_cover_every_edge_on_the_cube():
    from model.octree.geometry import cube_polygons, patch_probes
    rng = np.random.default_rng(1)
    n = rng.normal(size=(500, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    off = rng.uniform(-0.3, 0.3, 500)
    verts, count = cube_polygons(n, off, 1.0)
    probes = patch_probes(n, off, verts, count, 1.0, 1.0 / 16)
    live = np.arange(len(probes.edge_patch))
    pts = probes.edge_points(live)
    # on the plane, on the cube's surface (exactly), inside the cube
    assert np.allclose((pts.T * n[probes.edge_patch]).sum(1) + off[probes.edge_patch], 0, atol=1e-12)
    assert np.all(np.abs(pts).max(0) == 0.5)
    # every edge, the closing one included, has length: the probes are all distinct points
    unique = {(p, *np.round(x, 12)) for p, x in zip(probes.edge_patch, pts.T)}
    assert len(unique) == len(live)
    assert np.all(np.linalg.norm(probes.edge_b - probes.edge_a, axis=1) > 1e-9)


def test_no_sampling_gap_gives_finite_errors_and_the_same_octree():
    """A zero sample spacing (every gap tolerance 0) used to give NaN patch errors, read as
    leaves: the tolerance's boundary factor divided 0 by 0."""
    import warnings

    cloud = holey_sphere(20_000, seed=6)
    with warnings.catch_warnings():
        warnings.simplefilter("error", RuntimeWarning)
        fast = build_octree(cloud, 6, sample_spacing=0.0)
    for lv in fast.levels[fast.adaptive_depth:-1]:
        measured = lv.label != 0
        assert not np.isnan(lv.error[measured]).any()
        assert np.all(lv.error[lv.label == 2] <= fast.threshold)
    assert_same(fast, reference_build(cloud, 6, sample_spacing=0.0))


def test_an_error_exactly_at_the_threshold_does_not_split(monkeypatch):
    """The paper's rule: an octant splits iff delta_O > delta hat.  Errors are set to exactly the
    threshold for every other octant and to the next float above it for the rest."""
    seen = []

    def errors_at_the_boundary(pts, nrm, settings, centre, *args, **kwargs):
        err = np.full(len(centre), settings.threshold)
        err[1::2] = np.nextafter(settings.threshold, np.inf)
        seen.append(err)
        return err

    monkeypatch.setattr(build_module, "patch_errors", errors_at_the_boundary)
    o = build_octree(sphere_points(20_000), 6, neighbors=False)
    lv = o.levels[o.adaptive_depth]
    nonempty = lv.label != 0
    measured = seen[0]
    assert len(measured) == int(nonempty.sum()) >= 8
    assert np.array_equal(lv.label[nonempty] == 1, measured > o.threshold)
    assert (lv.label[nonempty] == 2).sum() == (measured == o.threshold).sum() > 0
