import numpy as np
import pytest

from model.octree import keys


def test_encode_decode_round_trip_with_batch():
    rng = np.random.default_rng(1)
    xyz = rng.integers(0, 1 << 16, size=(5000, 3))
    batch = rng.integers(0, 1 << 15, size=5000)
    k = keys.encode(xyz, batch)
    xyz2, batch2 = keys.decode(k)
    assert np.array_equal(xyz, xyz2) and np.array_equal(batch, batch2)


def test_children_are_consecutive_keys_and_slots_are_4x_2y_z():
    parent = np.array([[3, 5, 7]])
    pk = keys.encode(parent)[0]
    children = np.array([[6 + (s >> 2), 10 + ((s >> 1) & 1), 14 + (s & 1)] for s in range(8)])
    ck = keys.encode(children)
    assert np.array_equal(ck, (pk << np.uint64(3)) + np.arange(8, dtype=np.uint64))
    assert np.array_equal(keys.parent_keys(ck), np.full(8, pk))


def test_batch_bits_sort_shape_major_and_survive_parent():
    k = keys.encode(np.array([[9, 9, 9], [0, 0, 0]]), np.array([0, 1]))
    assert k[0] < k[1]
    assert np.array_equal(keys.batch_of(keys.parent_keys(k, 3)), [0, 1])


def test_depth_10_coordinates_fit_and_out_of_range_is_rejected():
    top = np.array([[1023, 1023, 1023]])
    assert np.array_equal(keys.decode(keys.encode(top))[0], top)
    with pytest.raises(ValueError):
        keys.encode(np.array([[1 << 16, 0, 0]]))


def test_child_keys_keep_the_batch_bits():
    k = keys.encode(np.array([[1, 2, 3], [1, 2, 3]]), np.array([0, 5]))
    ck = keys.child_keys(k)
    assert np.array_equal(keys.batch_of(ck), np.repeat([0, 5], 8))
    assert np.array_equal(keys.parent_keys(ck), np.repeat(k, 8))
    assert np.array_equal(keys.decode(ck[8:])[0], keys.decode(ck[:8])[0])


def test_lookup_finds_equal_keys_per_shape_and_points_past_the_end_otherwise():
    table = np.sort(keys.encode(np.array([[0, 0, 0], [1, 2, 3], [4, 4, 4], [1, 2, 3]]), np.array([0, 0, 0, 2])))
    query = keys.encode(np.array([[1, 2, 3], [1, 2, 3], [1, 2, 3], [7, 7, 7], [4, 4, 4]]), np.array([2, 0, 1, 0, 0]))
    rows = keys.lookup(table, query)
    assert rows.dtype == np.int64 and rows.tolist() == [3, 1, 4, 4, 2]     # shape 1 has no (1, 2, 3)
    assert keys.lookup(table[:0], query).tolist() == [0] * 5
    assert keys.lookup(table, query[:0]).shape == (0,)


def test_with_batch_replaces_only_the_batch_bits():
    k = keys.encode(np.array([[5, 6, 7], [1, 1, 1]]), np.array([3, 9]))
    moved = keys.with_batch(k, np.array([0, 1]))
    xyz, batch = keys.decode(moved)
    assert xyz.tolist() == [[5, 6, 7], [1, 1, 1]] and batch.tolist() == [0, 1]
