"""keep_scan: a completed octree fused with its scan's octree (observed octants keep the scan's patches)."""

import copy

import numpy as np
import pytest

from model.octree import EMPTY, LEAF, SPLIT, build_octree, scan_frame, scan_octree, validate
from model.octree import keys as morton
from model.octree.batch import merge_octrees
from model.octree.fuse import keep_scan
from model.octree.metrics import chamfer_distance, mean_squared_distance, sample_patches
from model.octree.neighbors import build_neighbors

from .conftest import sphere_points


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


def test_observed_octants_keep_the_scans_patches_and_the_rest_comes_from_the_output(sphere_case):
    pts, seen, frame, scan, whole = sphere_case
    fused = keep_scan(whole, scan)
    _check_structure(fused)
    got, mine, theirs = _leaves(fused), _leaves(scan), _leaves(whole)
    assert set(mine) <= set(got)                              # every scan leaf, with its own plane
    assert all(got[k] == mine[k] for k in mine)
    added = set(got) - set(mine)
    assert added and added <= set(theirs)                     # the rest: output leaves, unchanged
    assert all(got[k] == theirs[k] for k in added)
    for d, k in added:                                        # ... none where the scan has points
        lv = scan.levels[d]
        assert k not in set(lv.key[lv.label != EMPTY].tolist())
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


@pytest.mark.parametrize("bad", ["batched", "shallow"])
def test_bad_pairs_are_refused(sphere_case, bad):
    pts, _, frame, scan, whole = sphere_case
    if bad == "batched":
        with pytest.raises(ValueError, match="single-shape"):
            keep_scan(merge_octrees([whole, whole]), scan)
    else:
        with pytest.raises(ValueError, match="shallower"):
            keep_scan(whole, build_octree(validate(pts, None), 5, normalization=frame))
