"""keep_scan: a completed octree fused with its scan's octree (observed octants keep the scan's patches)."""

import copy

import numpy as np
import pytest
import trimesh

from model.octree import EMPTY, LEAF, SPLIT, Normalization, build_octree, scan_frame, scan_octree, validate
from model.octree import keys as morton
from model.octree.batch import merge_octrees
from model.octree.fuse import keep_scan
from model.octree.metrics import chamfer_distance, mean_squared_distance, sample_patches
from model.octree.neighbors import build_neighbors
from model.octree.patches import patches_to_mesh

from .conftest import sphere_points
from .reference_fuse import reference_leaves


def _leaves(tree):
    """{(depth, key): plane} of every leaf."""
    return {(lv.depth, int(k)): tuple(p) for lv in tree.levels
            for k, p in zip(lv.key[lv.label == LEAF], lv.plane[lv.label == LEAF])}


def _check_structure(tree):
    """Children of the k-th split octant are octants 8k..8k+7 with its child keys; parents match."""
    assert np.array_equal(tree.levels[0].key, np.zeros(1, np.uint64))
    for up, lv in zip(tree.levels, tree.levels[1:]):
        split = up.split_nodes()
        assert np.array_equal(split, np.flatnonzero(up.label == SPLIT))
        assert np.array_equal(lv.key, morton.child_keys(up.key[split]))
        assert np.array_equal(lv.parent, np.repeat(split, 8))
    assert not np.any(tree.levels[-1].label == SPLIT)
    for d in range(tree.full_depth):
        assert np.all(tree.levels[d].label == SPLIT)


@pytest.fixture(scope="module")
def sphere_case():
    """A sphere scanned with a hole (a band on its +x side) and, as the 'decoded' shape, the whole
    sphere in the scan's frame."""
    pts, nrm = sphere_points(40_000)
    seen = ~((np.abs(pts[:, 2]) < 0.4) & (pts[:, 0] > 0))
    frame = scan_frame(pts[seen])
    scan = scan_octree(validate(pts[seen], nrm[seen]), 6)
    whole = build_octree(validate(pts, nrm), 6, normalization=frame)
    return pts, seen, frame, scan, whole


def _leaf_plane(tree, depth, key):
    """(normal, normal . x) in cube units of the leaf of ``tree`` at or above octant (depth, key), or None."""
    for e in range(depth, -1, -1):
        lv = tree.levels[e]
        at = morton.lookup(lv.key, morton.parent_keys(np.array([key], np.uint64), depth - e))[0]
        if at < len(lv) and lv.label[at] == LEAF:
            n = lv.plane[at, :3].astype(np.float64)
            n /= np.linalg.norm(n)
            return n, float(n @ lv.centers()[at] - lv.plane_offsets()[at])
    return None


def _origins(fused, scan, whole):
    """Per leaf of ``fused``: 'scan' or 'output', checked to carry that tree's plane (its own leaf
    or the coarser leaf it was refined from)."""
    out = []
    for lv in fused.levels:
        centres = lv.centers()
        for i in np.flatnonzero(lv.label == LEAF):
            n = lv.plane[i, :3].astype(np.float64)
            n /= np.linalg.norm(n)
            level = float(n @ centres[i] - lv.plane_offsets()[i])
            found = [name for name, tree in (("scan", scan), ("output", whole))
                     if (p := _leaf_plane(tree, lv.depth, int(lv.key[i]))) is not None
                     and np.allclose(p[0], n, atol=1e-5) and abs(p[1] - level) < 1e-5]
            assert found, f"leaf ({lv.depth}, {lv.key[i]}) carries neither tree's plane"
            out.append(found[0])
    return out


def _area(tree):
    return patches_to_mesh(tree, world=False).area


def test_observed_octants_keep_the_scans_patches_and_the_rest_comes_from_the_output(sphere_case):
    pts, seen, frame, scan, whole = sphere_case
    fused = keep_scan(whole, scan)
    _check_structure(fused)
    origins = iter(_origins(fused, scan, whole))
    only_scan = copy.deepcopy(fused)                          # the fused tree's leaves from the scan
    outputs = 0
    for lv, mine in zip(only_scan.levels, scan.levels):
        seen_keys = set(mine.key[mine.label != EMPTY].tolist())
        for i in np.flatnonzero(lv.label == LEAF):
            if next(origins) == "output":
                assert int(lv.key[i]) not in seen_keys        # no output patch where the scan has points
                lv.label[i] = EMPTY
                outputs += 1
    assert outputs and fused.leaves_per_depth() != only_scan.leaves_per_depth()
    assert _area(only_scan) == pytest.approx(_area(scan), rel=1e-6)   # the scan's surface, all of it
    kept = set(_leaves(scan)) & set(_leaves(fused))           # most scan leaves as they are, a few refined
    assert len(kept) > 0.9 * len(_leaves(scan))
    assert fused.normalizations[0] is whole.normalizations[0]
    # the fused surface is the whole sphere: the unseen half is filled, the seen half is as good
    out = sample_patches(fused, 64)
    assert chamfer_distance(pts, out) < 1.5 * chamfer_distance(pts, sample_patches(whole, 64))
    unseen = pts[(np.abs(pts[:, 2]) < 0.2) & (pts[:, 0] > 0.2)]     # far from the hole's rim
    assert mean_squared_distance(unseen, out) < 0.01 * mean_squared_distance(unseen, sample_patches(scan, 64))


def test_an_empty_output_gives_the_scan_and_neighbours_can_be_built(sphere_case):
    _, _, _, scan, whole = sphere_case
    nothing = keep_scan(whole, whole)                        # drop every output leaf: observed everywhere
    assert _leaves(nothing) == _leaves(whole)
    blank = copy.deepcopy(whole)                             # an output with no leaf at all
    for lv in blank.levels:
        lv.label[lv.label == LEAF] = EMPTY
    assert not any(blank.leaves_per_depth())
    only_scan = keep_scan(blank, scan, neighbors=True)
    assert _leaves(only_scan) == _leaves(scan)
    assert only_scan.has_neighbors
    reference = keep_scan(blank, scan)
    build_neighbors(reference)
    assert all(np.array_equal(a.neighbors, b.neighbors) for a, b in zip(only_scan.levels, reference.levels))


def test_a_deeper_scan_is_cut_at_the_outputs_depth(sphere_case):
    pts, seen, frame, scan, _ = sphere_case
    coarse = build_octree(validate(pts, None), 4, normalization=frame)
    fused = keep_scan(coarse, scan)
    assert fused.depth == 4
    _check_structure(fused)
    cut, out = scan.levels[4], coarse.levels[4]
    seen4 = {int(k): tuple(p) for k, p in zip(cut.key[cut.label != EMPTY], cut.plane[cut.label != EMPTY])}
    theirs = {int(k): tuple(p) for k, p in zip(out.key[out.label == LEAF], out.plane[out.label == LEAF])}
    got4 = {k: p for (d, k), p in _leaves(fused).items() if d == 4}
    assert {k: got4[k] for k in seen4} == seen4               # the scan's depth-4 octants became leaves
    assert {k: p for k, p in got4.items() if k not in seen4} == {k: p for k, p in theirs.items() if k not in seen4}


def _box_points(extents, n=60_000, seed=0):
    box = trimesh.creation.box(extents=extents)
    pts, face = trimesh.sample.sample_surface_even(box, n, seed=seed)
    return pts, box.face_normals[face]


def test_an_output_leaf_the_scan_saw_a_corner_of_keeps_its_patch_elsewhere():
    """A flat square decoded as coarse leaves, scanned only in a small disk: the leaves around the
    disk are refined, not dropped, so the fused square has no hole."""
    pts, nrm = _box_points((1.6, 1.6, 0.02))
    top = nrm[:, 2] > 0.5
    pts, nrm = pts[top], nrm[top]
    frame = scan_frame(pts)
    whole = build_octree(validate(pts, nrm), 6, normalization=frame)
    assert whole.leaves_per_depth()[4] > 0                    # coarse leaves on the flat square
    disk = np.linalg.norm(pts[:, :2] - [0.3, 0.3], axis=1) < 0.05
    scan = build_octree(validate(pts[disk], nrm[disk]), 6, normalization=frame)
    fused = keep_scan(whole, scan)
    _check_structure(fused)
    assert set(_origins(fused, scan, whole)) == {"scan", "output"}
    assert _area(fused) == pytest.approx(_area(whole), rel=1e-4)      # the whole square, no hole
    around = pts[~disk & (np.linalg.norm(pts[:, :2] - [0.3, 0.3], axis=1) < 0.15)]
    assert mean_squared_distance(around, sample_patches(fused, 128)) < \
        1.5 * mean_squared_distance(around, sample_patches(whole, 128))


def test_a_coarse_scan_leaf_keeps_the_surfaces_it_did_not_see():
    """A thin plate scanned from above: the scan's top face becomes coarse leaves, and the decoded
    bottom face inside those octants is kept (the top face's decoded copy is not)."""
    pts, nrm = _box_points((1.6, 1.6, 0.08))
    frame = scan_frame(pts)          # moved so both faces lie in the same depth-4 octants
    frame = Normalization(center=frame.center - [0, 0, 0.03 * frame.scale], scale=frame.scale)
    assert len(np.unique(np.floor(frame.to_cube(pts)[:, 2] * 16))) == 1
    whole = build_octree(validate(pts, nrm), 6, normalization=frame)
    top, bottom = nrm[:, 2] > 0.5, nrm[:, 2] < -0.5
    scan = build_octree(validate(pts[top], nrm[top]), 6, normalization=frame)
    assert scan.leaves_per_depth()[4] > 0
    fused = keep_scan(whole, scan)
    _check_structure(fused)
    origins = _origins(fused, scan, whole)
    assert set(origins) == {"scan", "output"}
    near = mean_squared_distance(pts[bottom], sample_patches(fused, 128))
    assert near < 1.5 * mean_squared_distance(pts[bottom], sample_patches(whole, 128))
    assert near < 0.02 * mean_squared_distance(pts[bottom], sample_patches(scan, 128))
    upward = [o for o, lv_n in zip(origins, _leaf_normals(fused)) if lv_n[2] > 0.9]
    assert upward and set(upward) == {"scan"}                 # the top face is the scan's alone
    assert _area(fused) < 1.05 * _area(whole)


def _leaf_normals(tree):
    return [lv.plane[i, :3] / np.linalg.norm(lv.plane[i, :3]) for lv in tree.levels
            for i in np.flatnonzero(lv.label == LEAF)]


@pytest.mark.parametrize("bad", ["batched", "shallow"])
def test_bad_pairs_are_refused(sphere_case, bad):
    pts, _, frame, scan, whole = sphere_case
    if bad == "batched":
        with pytest.raises(ValueError, match="single-shape"):
            keep_scan(merge_octrees([whole, whole]), scan)
    else:
        with pytest.raises(ValueError, match="shallower"):
            keep_scan(whole, build_octree(validate(pts, None), 5, normalization=frame))


def _fused_leaves(tree):
    """{(depth, key): (plane bytes, error bytes, point count)} of every leaf of ``tree``."""
    return {(lv.depth, int(k)): (p.tobytes(), e.tobytes(), int(c)) for lv in tree.levels
            for k, p, e, c in zip(lv.key[lv.label == LEAF], lv.plane[lv.label == LEAF],
                                  lv.error[lv.label == LEAF], lv.npoints[lv.label == LEAF])}


def _jittered(tree, seed):
    """``tree`` with every leaf's plane turned and moved a little (a decoded output's planes)."""
    out = copy.deepcopy(tree)
    rng = np.random.default_rng(seed)
    for lv in out.levels:
        lv.plane = (lv.plane + rng.normal(0, 0.2, lv.plane.shape) * (lv.label != EMPTY)[:, None]).astype(np.float32)
    return out


@pytest.mark.parametrize("case", ["sphere", "jittered", "box", "deeper scan", "full output", "full scan",
                                  "shallow output"])
def test_the_compiled_walk_gives_the_reference_fusions_leaves_bit_for_bit(sphere_case, case):
    """Against the plain NumPy fusion (tests/octree/reference_fuse.py): the same leaves, planes,
    errors and point counts, bit for bit, where the trees agree, where a scan leaf is refined
    under the output's splits (and the reverse), claimed, or cut from a deeper scan."""
    pts, seen, frame, scan, whole = sphere_case
    nrm = sphere_points(40_000)[1]
    if case == "jittered":
        whole = _jittered(whole, 0)
    elif case == "box":
        box = trimesh.creation.box((1.2, 0.7, 0.9))
        p, f = trimesh.sample.sample_surface(box, 30_000, seed=1)
        whole = build_octree(validate(p, box.face_normals[f]), 6, normalization=frame)
    elif case == "deeper scan":
        scan = scan_octree(validate(pts[seen], nrm[seen]), 7)
    elif case == "full output":               # every coarse scan leaf refined, its plane claiming nearby octants
        whole = _jittered(build_octree(validate(pts, nrm), 6, normalization=frame, adaptive=False), 1)
    elif case == "full scan":                 # every coarse output leaf refined under the scan's splits
        scan = scan_octree(validate(pts[seen], nrm[seen]), 6, adaptive=False)
    elif case == "shallow output":            # an output at its full depth under a scan four levels deeper
        whole = build_octree(validate(pts, nrm), 2, normalization=frame)
    fused = keep_scan(whole, scan)
    _check_structure(fused)
    want = reference_leaves(whole, scan)
    assert len(want) > (40 if case == "shallow output" else 1000)
    assert _fused_leaves(fused) == want


def _walked(decoded, scan):
    """The compiled walk's leaves of ``keep_scan(decoded, scan)`` (depth, key, plane, error, count)."""
    from model.octree.fuse import _flat, _walk

    s, o = _flat(scan, decoded.depth), _flat(decoded, decoded.depth)
    return _walk(decoded.depth, float(scan.threshold), s.start, s.label, s.child, s.live, s.plane, s.error,
                 s.npoints, o.start, o.label, o.child, o.live, o.plane, o.error, o.npoints)


def _by_depth(depth, at, key, plane, error, npoints):
    return [(key[at == d], plane[at == d], error[at == d], npoints[at == d]) if (at == d).any() else None
            for d in range(depth + 1)]


@pytest.mark.parametrize("case", ["sphere", "jittered", "full output", "full scan", "shallow output",
                                  "no full depth", "depth 1"])
def test_the_fused_tree_is_the_reference_construction_array_for_array(sphere_case, case):
    """The compiled construction of the fused tree from its leaves against the NumPy formulation
    (tests/octree/reference_fuse.py): every level's keys, labels, children, parents, planes,
    errors (NaN where no leaf) and point counts, bit for bit and in their dtypes."""
    from .reference_fuse import reference_tree

    pts, seen, frame, scan, whole = sphere_case
    nrm = sphere_points(40_000)[1]
    if case == "jittered":
        whole = _jittered(whole, 2)
    elif case == "full output":
        whole = _jittered(build_octree(validate(pts, nrm), 6, normalization=frame, adaptive=False), 1)
    elif case == "full scan":
        scan = scan_octree(validate(pts[seen], nrm[seen]), 6, adaptive=False)
    elif case == "shallow output":
        whole = build_octree(validate(pts, nrm), 2, normalization=frame)
    elif case == "no full depth":             # nothing split for its depth alone: only a leaf's ancestors
        whole = build_octree(validate(pts, nrm), 6, normalization=frame, full_depth=0)
        scan = scan_octree(validate(pts[seen], nrm[seen]), 6, full_depth=0)
    elif case == "depth 1":                   # the shallowest output, nothing split for its depth alone
        whole = build_octree(validate(pts, nrm), 1, normalization=frame, full_depth=0)
    fused = keep_scan(whole, scan)
    want = reference_tree(whole, _by_depth(whole.depth, *_walked(whole, scan)))
    assert len(fused.levels) == len(want.levels) == whole.depth + 1
    for got, ref in zip(fused.levels, want.levels):
        for field in ("key", "label", "child", "parent", "plane", "error", "npoints"):
            a, b = getattr(got, field), getattr(ref, field)
            assert a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes(), (case, got.depth, field)
    assert (fused.full_depth, fused.adaptive_depth, fused.threshold) == (whole.full_depth, whole.adaptive_depth,
                                                                           whole.threshold)


def test_leaves_that_nest_or_split_are_refused_as_before():
    """The construction refuses what the walk never emits, with the reference's messages: a leaf
    inside another leaf, a leaf above the full depth, a key outside its depth's cube, a depth's
    keys out of order."""
    from model.octree.fuse import _from_leaves

    from .reference_fuse import reference_tree

    like = build_octree(validate(*sphere_points(2_000)), 3)
    plane = np.zeros((2, 4), np.float32)
    error, count = np.zeros(2, np.float32), np.zeros(2, np.int32)
    nested = (np.array([2, 3]), np.array([9, 9 * 8 + 1], np.uint64))        # depth-3 key 73 lies inside leaf 9
    above = (np.array([0, 3]), np.array([0, 100], np.uint64))                # the root a leaf under full depth
    outside = (np.array([3, 3]), np.array([5, 600], np.uint64))              # depth 3 has keys below 8^3 = 512
    for (at, key), message in ((nested, "depth 2: a leaf contains another leaf"),
                               (above, "depth 0: a leaf contains another leaf"),
                               (outside, "depth 3: leaves nest or lie outside the tree")):
        with pytest.raises(ValueError, match=message):
            _from_leaves(like, at, key, plane, error, count, False)
        with pytest.raises(ValueError, match=message):
            reference_tree(like, _by_depth(3, at, key, plane, error, count))
    with pytest.raises(ValueError, match="depth 3: the leaves' keys are not ascending"):
        _from_leaves(like, np.array([3, 3]), np.array([100, 90], np.uint64), plane, error, count, False)
