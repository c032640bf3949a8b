"""Exact k-nearest neighbours of every point of a cloud among the cloud, on a uniform grid
(compiled with numba): the neighbourhoods of normal estimation, 2-3x faster than SciPy's cKDTree.

Invariants: :func:`nearest` returns exactly what ``cKDTree(points).query(points, k)[1]`` returns.
The grid search (:func:`_query`) finds each point's ``k + 1`` nearest in ascending order of squared
distance computed as ``dx*dx + dy*dy + dz*dz`` (left to right, as cKDTree computes it), ties by
index, and stops only when no unvisited cell can hold a point at a distance lower than or equal to
the last found; rows where two of those distances are equal (where cKDTree's own order of ties,
which follows its tree, decides the order or even the set) are asked of cKDTree itself.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numba
import numpy as np
from scipy.spatial import cKDTree

MAX_CELLS_PER_AXIS = 128
"""The grid's resolution is capped so that its cell table stays a few megabytes."""
FILL = 0.5
"""The grid aims at ``FILL * k`` points per occupied cell: the k nearest then mostly lie within
the point's cell and the 26 around it, and few of those 27 cells' points are not among them."""
THREADS = 2
"""Queries split in this many contiguous parts, each in its own thread (the kernel releases the GIL)."""
TIED_SHARE = 0.2
"""Above this share of rows with tied distances (points on a lattice), cKDTree answers them all."""


def _grid(pts: np.ndarray, lo: np.ndarray, extent: float, k: int) -> tuple[float, int, np.ndarray, np.ndarray]:
    """(cell, cells per axis, order, start) of a grid holding about ``FILL * k`` points per occupied
    cell: first sized for a surface (occupied cells growing as the square of the resolution), then
    coarsened once if the points fill a volume (a solid cloud) and the cells come out too sparse."""
    n = len(pts)
    want = FILL * k
    g = int(np.clip(np.sqrt(n / want), 1, MAX_CELLS_PER_AXIS))
    cell = extent / g if extent > 0 else 1.0
    order, start = _bucket(pts, lo, cell, g)
    per_cell = n / max(int(np.count_nonzero(np.diff(start))), 1)
    if per_cell < want / 2 and g > 1:
        g = max(int(g * (per_cell / want) ** (1 / 3)), 1)
        cell = extent / g if extent > 0 else 1.0
        order, start = _bucket(pts, lo, cell, g)
    return cell, g, order, start


@numba.njit(cache=True, nogil=True)
def _bucket(points: np.ndarray, lo: np.ndarray, cell: float, g: int) -> tuple[np.ndarray, np.ndarray]:
    """Points sorted by grid cell (counting sort, stable): (order (n,), start (g^3 + 1,))."""
    n = len(points)
    cid = np.empty(n, np.int64)
    count = np.zeros(g * g * g + 1, np.int64)
    for i in range(n):
        c = 0
        for a in range(3):
            q = int((points[i, a] - lo[a]) / cell)
            c = c * g + min(max(q, 0), g - 1)
        cid[i] = c
        count[c + 1] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        order[fill[cid[i]]] = i
        fill[cid[i]] += 1
    return order, start


@numba.njit(cache=True, nogil=True)
def _query(points: np.ndarray, first: int, last: int, k: int, order: np.ndarray, start: np.ndarray,
           lo: np.ndarray, cell: float, g: int, out: np.ndarray, tied: np.ndarray) -> None:
    """The ``k`` nearest (ties by index) of the points ``order[first:last]``, written into rows
    ``order[first:last]`` of ``out``, and whether two of their distances are equal into ``tied``;
    ``points`` are sorted by cell (``points[s]`` is the input's ``order[s]``)."""
    best_d = np.empty(k)
    best_i = np.empty(k, np.int64)
    c = np.empty(3, np.int64)
    for i in range(first, last):
        x, y, z = points[i, 0], points[i, 1], points[i, 2]
        for a in range(3):
            c[a] = min(max(int((points[i, a] - lo[a]) / cell), 0), g - 1)
        found = 0
        r = 0
        while True:
            for cx in range(max(c[0] - r, 0), min(c[0] + r, g - 1) + 1):
                for cy in range(max(c[1] - r, 0), min(c[1] + r, g - 1) + 1):
                    for cz in range(max(c[2] - r, 0), min(c[2] + r, g - 1) + 1):
                        if max(abs(cx - c[0]), abs(cy - c[1]), abs(cz - c[2])) != r:
                            continue                        # visited in an earlier ring
                        cid = (cx * g + cy) * g + cz
                        for s in range(start[cid], start[cid + 1]):
                            j = order[s]
                            dx = x - points[s, 0]
                            dy = y - points[s, 1]
                            dz = z - points[s, 2]
                            d = dx * dx + dy * dy + dz * dz
                            if found == k and (d > best_d[k - 1] or (d == best_d[k - 1] and j > best_i[k - 1])):
                                continue
                            p = found if found < k else k - 1
                            while p > 0 and (best_d[p - 1] > d or (best_d[p - 1] == d and best_i[p - 1] > j)):
                                best_d[p] = best_d[p - 1]
                                best_i[p] = best_i[p - 1]
                                p -= 1
                            best_d[p] = d
                            best_i[p] = j
                            if found < k:
                                found += 1
            # Distance from the point to the outside of the cells visited so far (inf: all of them).
            gap = np.inf
            for a in range(3):
                if c[a] - r > 0:
                    gap = min(gap, points[i, a] - (lo[a] + (c[a] - r) * cell))
                if c[a] + r < g - 1:
                    gap = min(gap, lo[a] + (c[a] + r + 1) * cell - points[i, a])
            gap *= 1.0 - 1e-9                               # a point binned across a rounding
            if gap == np.inf or (found == k and best_d[k - 1] < gap * gap):
                break
            r += 1
        tie = False
        for m in range(k):
            out[order[i], m] = best_i[m]
            if m > 0 and best_d[m] == best_d[m - 1]:
                tie = True
        tied[order[i]] = tie


def nearest(points: np.ndarray, k: int, threads: int = THREADS) -> np.ndarray:
    """(n, k) int64: the indices of the ``k`` nearest points of each of ``points`` (n, 3) among
    them, as cKDTree gives them (module invariants); 1 <= ``k`` <= n."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = len(pts)
    if not 1 <= k <= n:
        raise ValueError(f"k must be in 1..{n}, got {k}")
    wide = min(k + 1, n)                         # one more: a tie for the last place shows
    found, tied = _grid_nearest(pts, wide, threads)
    found = found[:, :k]
    rows = np.flatnonzero(tied)
    if len(rows) > TIED_SHARE * n:               # a lattice: the tree answers every row at once
        return cKDTree(pts).query(pts, k=k, workers=threads)[1].reshape(n, k).astype(np.int64)
    if len(rows):
        found[rows] = cKDTree(pts).query(pts[rows], k=k, workers=threads)[1].reshape(len(rows), k)
    return np.ascontiguousarray(found)


def _grid_nearest(pts: np.ndarray, k: int, threads: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, k) nearest by the grid search, ties by index, and (n,) whether a row holds a tie."""
    n = len(pts)
    lo = pts.min(0)
    extent = float((pts.max(0) - lo).max())
    cell, g, order, start = _grid(pts, lo, extent, k)
    sorted_pts = pts[order]
    out = np.empty((n, k), np.int64)
    tied = np.empty(n, np.bool_)
    bounds = np.linspace(0, n, max(1, min(threads, n)) + 1).astype(np.int64)
    parts = list(zip(bounds[:-1].tolist(), bounds[1:].tolist()))

    def run(part: tuple[int, int]) -> None:
        _query(sorted_pts, part[0], part[1], k, order, start, lo, cell, g, out, tied)

    if len(parts) == 1:
        run(parts[0])
    else:
        with ThreadPoolExecutor(len(parts)) as pool:
            list(pool.map(run, parts))
    return out, tied
