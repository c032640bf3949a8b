"""The grid k-nearest-neighbour search: exactly cKDTree's answer, ties included."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial import cKDTree

from model.data import generate, scan
from model.octree import knn
from model.octree.knn import NeighbourGrid, _grid_nearest, nearest


def reference(points: np.ndarray, k: int) -> np.ndarray:
    return cKDTree(points).query(points, k=k)[1].reshape(len(points), k)


def clouds() -> dict[str, np.ndarray]:
    rng = np.random.default_rng(3)
    lattice = np.stack(np.meshgrid(*[np.arange(12.0)] * 3), -1).reshape(-1, 3)
    return {
        "scan with tied distances": scan(generate("airplane", 7), resolution=128)[0][::2].astype(np.float64),
        "random volume": rng.random((6000, 3)),
        "sphere surface": (lambda p: p / np.linalg.norm(p, axis=1, keepdims=True))(rng.normal(size=(8000, 3))),
        "duplicated points": np.repeat(rng.random((1500, 3)), 3, axis=0),
        "lattice": lattice,
        "far cluster": np.concatenate([rng.random((3000, 3)), 1e4 + rng.random((20, 3))]),
    }


@pytest.mark.parametrize("name", list(clouds()))
def test_the_neighbours_are_cKDTree_s(name):
    points = clouds()[name]
    assert np.array_equal(nearest(points, 16), reference(points, 16))


def test_one_thread_and_two_agree_and_k_spans_1_to_n():
    points = clouds()["scan with tied distances"]
    assert np.array_equal(nearest(points, 16, threads=1), nearest(points, 16, threads=2))
    small = points[:9]
    for k in (1, 2, 9):
        assert np.array_equal(nearest(small, k), reference(small, k))


def test_the_grid_search_orders_ties_by_index_and_flags_them():
    """Brute force over a cloud full of ties (a lattice with duplicates): the grid's rows are the
    (distance, index) order, and exactly the rows with two equal distances are flagged."""
    lattice = np.stack(np.meshgrid(*[np.arange(6.0)] * 3), -1).reshape(-1, 3)
    points = np.concatenate([lattice, lattice[::7], np.random.default_rng(0).random((40, 3)) * 5])
    k = 10
    found, tied = _grid_nearest(points, k, threads=2)
    d = ((points[:, None] - points[None]) ** 2).sum(-1)
    for i in range(len(points)):
        want = np.lexsort((np.arange(len(points)), d[i]))[:k]
        assert np.array_equal(found[i], want)
        assert tied[i] == bool((np.diff(d[i, want]) == 0).any())
    assert tied.any() and not tied.all()


def test_a_cloud_mostly_tied_is_answered_by_the_tree(monkeypatch):
    """Above the tied share the whole cloud goes to cKDTree; below it only the tied rows."""
    points = clouds()["lattice"]
    assert np.array_equal(nearest(points, 8), reference(points, 8))
    monkeypatch.setattr(knn, "TIED_SHARE", 1.0)
    assert np.array_equal(nearest(points, 8), reference(points, 8))


def test_k_out_of_range_is_refused():
    with pytest.raises(ValueError, match="k must be in 1..5"):
        nearest(np.random.default_rng(0).random((5, 3)), 6)


@pytest.mark.parametrize("name", ["random volume", "lattice", "duplicated points", "scan with tied distances"])
def test_queries_within_a_radius_are_cKDTree_s(name):
    """Nearest within a radius (distances, indices: inf and n where none) and hits, for queries
    inside, around and far outside the cloud, at radii from below the spacing to above it; the
    lattice's radius equal to its spacing puts points exactly on the bound."""
    points = clouds()[name]
    rng = np.random.default_rng(5)
    lo, hi = points.min(0), points.max(0)
    queries = np.concatenate([lo + (hi - lo) * (rng.random((3000, 3)) * 1.4 - 0.2), points[:800],
                              points[:300] + 0.01 * (hi - lo), [hi + 10 * (hi - lo)]])
    tree = cKDTree(points)
    grid = NeighbourGrid(points)
    spacing = float(np.median(tree.query(points[:500], k=2)[0][:, 1]))
    for radius in (0.3 * spacing, spacing, 3 * spacing, 0.2 * float((hi - lo).max())):
        dist, index = tree.query(queries, distance_upper_bound=radius)
        got = grid.nearest(queries, radius)
        assert np.array_equal(got[0], dist) and np.array_equal(got[1], index)
        assert np.array_equal(grid.hits(queries, radius), dist < radius)
    assert 0 < (dist < np.inf).mean() < 1


def _border_pairs(count: int, seed: int):
    """Clouds with two points A and B on either side of a grid cell's border, B binned across it by
    rounding though it lies a few units in the last place below the border as computed, and a query
    midway (a tie) in the cell below: (points, query, the grid's cell)."""
    rng = np.random.default_rng(seed)
    made = 0
    while made < count:
        g = int(rng.integers(3, 13))
        n = int(np.ceil(g ** 3 / 2)) + 1
        if int(np.clip(np.cbrt(2 * n), 1, 128)) != g:          # NeighbourGrid's resolution for n points
            continue
        hi = float(rng.random() * 3 + 0.1)
        cell = hi / g
        c = int(rng.integers(0, g - 1))
        b = B = (c + 1) * cell
        found = False
        for _ in range(4):
            if int(B / cell) == c + 1:
                q = np.nextafter(B, -1.0)
                d = B - q
                A = q - d
                if q - A == d and np.floor(q / cell) == c and int(A / cell) == c and (b - q) ** 2 > d * d:
                    found = True
                    break
            B = np.nextafter(B, -1.0)
        if not found:
            continue
        fill = rng.random((n - 4, 3)) * [hi, 1, 1]
        pos = int(rng.integers(0, n - 3))
        pair = [[B, 0.5, 0.5], [A, 0.5, 0.5]] if made % 2 else [[A, 0.5, 0.5], [B, 0.5, 0.5]]
        made += 1
        yield np.r_[[[0.0, 0, 0], [hi, 1, 1]], fill[:pos], pair, fill[pos:]], np.array([[q, 0.5, 0.5]]), cell


def test_points_binned_across_a_border_by_rounding_are_still_found():
    """A cell is skipped only when its border, shrunk by the rounding of the binning (units in the
    last place of the coordinates, not only a share of the gap), lies beyond the nearest found."""
    for points, query, cell in _border_pairs(40, seed=1):
        tree = cKDTree(points)
        dist, index = tree.query(query, distance_upper_bound=0.5 * cell)
        got = NeighbourGrid(points).nearest(query, 0.5 * cell)
        assert np.array_equal(got[0], dist) and np.array_equal(got[1], index)
        both = np.concatenate([points, query])                  # the query a point of the cloud: its 3 nearest
        assert np.array_equal(nearest(both, 3)[-1], reference(both, 3)[-1])
