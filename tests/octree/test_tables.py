import numpy as np
import trimesh

from model.octree import build_octree, keys
from model.octree.batch import merge_octrees
from model.octree.neighbors import CENTER

from .conftest import mesh_path, mesh_points, sphere_points


def neighbors_by_key_search(level) -> np.ndarray:
    """Independent reference: look every 3x3x3 neighbour key up among the level's keys."""
    xyz, batch = keys.decode(level.key)
    res = 1 << level.depth
    out = np.full((len(level), 27), -1, dtype=np.int64)
    for o in range(27):
        d = np.array([o // 9, (o // 3) % 3, o % 3]) - 1
        q = xyz + d
        ok = np.all((q >= 0) & (q < res), axis=1)
        k = keys.encode(np.clip(q, 0, res - 1), batch)
        pos = np.minimum(np.searchsorted(level.key, k), len(level) - 1)
        hit = ok & (level.key[pos] == k)
        out[hit, o] = pos[hit]
    return out


def test_neighbor_tables_match_key_search_at_every_depth():
    pts, nrm = sphere_points(30_000)
    o = build_octree((pts, nrm), 6)
    for lv in o.levels:
        assert lv.neighbors.dtype == np.int32
        assert np.array_equal(lv.neighbors, neighbors_by_key_search(lv))
        assert np.array_equal(lv.neighbors[:, CENTER], np.arange(len(lv)))


def test_batched_tables_equal_per_shape_tables_offset_and_never_cross_shapes():
    box = trimesh.creation.box(extents=(1.0, 0.5, 0.3))
    shapes = [sphere_points(20_000), mesh_points(box, 20_000),
              mesh_points(trimesh.load(mesh_path("chair_soup.off"), force="mesh"), 20_000)]
    singles = [build_octree(s, 6, adaptive=(i != 1)) for i, s in enumerate(shapes)]
    merged = merge_octrees(singles)
    assert merged.batch_size == 3
    for d in range(7):
        lv = merged.levels[d]
        parts = [s.levels[d] for s in singles]
        n_off = np.cumsum([0] + [len(p) for p in parts])[:-1]
        c_off = np.cumsum([0] + [int((p.child >= 0).sum()) for p in parts])[:-1]
        assert np.array_equal(lv.batch, np.repeat(np.arange(3), [len(p) for p in parts]))
        for b, (p, n0, c0) in enumerate(zip(parts, n_off, c_off)):
            sl = slice(n0, n0 + len(p))
            assert np.array_equal(lv.neighbors[sl], np.where(p.neighbors >= 0, p.neighbors + n0, -1))
            assert np.array_equal(lv.child[sl], np.where(p.child >= 0, p.child + c0, -1))
            assert np.array_equal(lv.plane[sl], p.plane)
            assert np.array_equal(lv.label[sl], p.label)
            valid = lv.neighbors[sl] >= 0
            assert np.all(lv.batch[lv.neighbors[sl][valid]] == b)
        assert np.array_equal(lv.neighbors, neighbors_by_key_search(lv))
        if d > 0:
            up = merged.levels[d - 1]
            split = np.flatnonzero(up.child >= 0)
            assert np.array_equal(lv.parent, np.repeat(split, 8))
            assert np.array_equal(keys.parent_keys(lv.key), up.key[lv.parent])


def test_octree_round_trips_through_flat_arrays(tmp_path):
    from model.octree.serialize import octree_from_arrays, octree_to_arrays

    pts, nrm = sphere_points(20_000)
    o = merge_octrees([build_octree((pts, nrm), 6), build_octree((pts * 2, nrm), 6)])
    np.savez(tmp_path / "o.npz", **octree_to_arrays(o, prefix="ad_"))
    with np.load(tmp_path / "o.npz") as f:
        back = octree_from_arrays(f, prefix="ad_")
    assert back.batch_size == 2 and back.adaptive and back.threshold == o.threshold
    for a, b in zip(o.levels, back.levels):
        for name in ("key", "label", "child", "parent", "plane", "npoints", "neighbors"):
            assert np.array_equal(getattr(a, name), getattr(b, name)), name
        assert np.array_equal(a.error, b.error, equal_nan=True)
    assert np.allclose(back.normalizations[1].scale, 2 * o.normalizations[0].scale)


def test_split_octree_inverts_merge():
    from model.octree.batch import split_octree

    singles = [build_octree(sphere_points(8000, seed=s), 5, adaptive=bool(s % 2)) for s in range(3)]
    back = split_octree(merge_octrees(singles))
    assert len(back) == 3
    for a, b in zip(singles, back):
        for la, lb in zip(a.levels, b.levels):
            for name in ("key", "label", "child", "parent", "plane", "npoints", "neighbors"):
                assert np.array_equal(getattr(la, name), getattr(lb, name)), name
    bare = split_octree(merge_octrees(singles), neighbors=False)   # for meshing: no tables rebuilt
    for a, b in zip(singles, bare):
        assert not b.has_neighbors
        for la, lb in zip(a.levels, b.levels):
            assert np.array_equal(la.key, lb.key) and np.array_equal(la.child, lb.child)


def test_a_single_octree_merged_is_itself_and_left_untouched():
    """One octree is its own batch: the same tables as merging it beside another and taking the
    first shape's part; asking for neighbour tables builds them on the merged tree only."""
    a = build_octree(sphere_points(8000, seed=1), 5, neighbors=False)
    b = build_octree(sphere_points(6000, seed=2), 5, neighbors=False)
    single = merge_octrees([a], neighbors=True)
    pair = merge_octrees([a, b], neighbors=True)
    for lv_a, lv_1, lv_2 in zip(a.levels, single.levels, pair.levels):
        n = len(lv_a)
        assert lv_a.neighbors is None                       # the input keeps its own (absent) tables
        for name in ("key", "label", "child", "parent", "plane", "npoints", "neighbors"):
            got, want = getattr(lv_1, name), getattr(lv_2, name)[:n]
            assert got.dtype == want.dtype and np.array_equal(got, want), name
        assert np.array_equal(lv_1.error, lv_2.error[:n], equal_nan=True)
    assert single.normalizations == a.normalizations and single.normalizations is not a.normalizations
