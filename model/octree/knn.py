"""Exact nearest neighbours on a uniform grid (compiled with numba), giving what SciPy's cKDTree
gives in about half its time: the k nearest of every point of a cloud (:func:`nearest`, the
neighbourhoods of normal estimation), the distances to the k nearest of other points
(:func:`nearest_distances`, the octree's sampling-spacing estimate) and the nearest within a
radius (:class:`NeighbourGrid`, the symmetry search).

Invariants: :func:`nearest` returns exactly ``cKDTree(points).query(points, k)[1]``.  The grid
search (:func:`_query`) finds each point's ``k + 1`` nearest in ascending order of squared
distance computed as ``dx*dx + dy*dy + dz*dz`` (left to right, as cKDTree computes it), ties by
index, and stops only when no unvisited cell can hold a point at a distance lower than or equal to
the last found; rows where two of those distances are equal (where cKDTree's own order of ties,
which follows its tree, decides the order or even the set) are asked of cKDTree itself.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from .geometry import bounding_box
from .jit import compiled, inlined
from .parallel import WORKERS, run_parts

MAX_CELLS_PER_AXIS = 128
"""The grid's resolution is capped so that its cell table stays a few megabytes."""
CELLS_PER_POINT = 2
"""The grid holds at most this many cells per point (all cells are counted, most are empty)."""
FILL = 0.5
"""The grid aims at ``FILL * k`` points per occupied cell: the k nearest then mostly lie within
the point's cell and the 26 around it, and few of those 27 cells' points are not among them."""
TIED_SHARE = 0.2
"""Above this share of rows with tied distances (points on a lattice), cKDTree answers them all."""


def _grid(pts: np.ndarray, lo: np.ndarray, extent: float, k: int) -> tuple[float, int, np.ndarray, np.ndarray]:
    """(cell, cells per axis, order, start) of a grid holding about ``FILL * k`` points per occupied
    cell: first sized for a surface (occupied cells growing as the square of the resolution), then
    coarsened once if the points fill a volume (a solid cloud) and the cells come out too sparse."""
    n = len(pts)
    want = FILL * k
    g = int(np.clip(min(np.sqrt(n / want), np.cbrt(CELLS_PER_POINT * n)), 1, MAX_CELLS_PER_AXIS))
    cell = extent / g if extent > 0 else 1.0
    order, start = _bucket(pts, lo, cell, g)
    per_cell = n / max(int(np.count_nonzero(np.diff(start))), 1)
    if per_cell < want / 2 and g > 1:
        g = max(int(g * (per_cell / want) ** (1 / 3)), 1)
        cell = extent / g if extent > 0 else 1.0
        order, start = _bucket(pts, lo, cell, g)
    return cell, g, order, start


@compiled
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


@inlined
def _scan_cell(points: np.ndarray, order: np.ndarray, start: np.ndarray, cid: int, x: float, y: float, z: float,
               k: int, best_d: np.ndarray, best_i: np.ndarray, n_found: int) -> int:
    """The points of cell ``cid`` offered to the ``k`` best so far (``best_d``, ``best_i``, the
    first ``n_found`` of them filled, ascending by squared distance, ties by index); returns how
    many are filled."""
    for s in range(start[cid], start[cid + 1]):
        j = order[s]
        dx = x - points[s, 0]
        dy = y - points[s, 1]
        dz = z - points[s, 2]
        d = dx * dx + dy * dy + dz * dz
        if n_found == k and (d > best_d[k - 1] or (d == best_d[k - 1] and j > best_i[k - 1])):
            continue
        p = n_found if n_found < k else k - 1
        while p > 0 and (best_d[p - 1] > d or (best_d[p - 1] == d and best_i[p - 1] > j)):
            best_d[p] = best_d[p - 1]
            best_i[p] = best_i[p - 1]
            p -= 1
        best_d[p] = d
        best_i[p] = j
        if n_found < k:
            n_found += 1
    return n_found


ROUNDING = 16 * np.finfo(np.float64).eps
"""A point lies within this share of the coordinates' size of a cell border it was binned across by
rounding (``(p - lo) / cell`` and the border ``lo + c * cell`` round a few units in the last place)."""


@inlined
def _shrunk(gap: float, scale: float) -> float:
    """A gap between a query and a cell border made a lower bound of the distance to any point
    binned beyond it: less a share of itself and :data:`ROUNDING` of the coordinates' size ``scale``."""
    return max(gap * (1.0 - 1e-9) - ROUNDING * scale, 0.0)


@inlined
def _side_gap(q: float, lo: float, c: int, o: int, cell: float) -> float:
    """Along one axis, the distance from ``q`` (in cell ``c``) to the cell ``c + o`` (0 for o = 0),
    shrunk by the rounding margin of the cells' bounds (:func:`_shrunk`: a point binned across a
    rounding)."""
    if o == 0:
        return 0.0
    gap = lo + (c + 1) * cell - q if o > 0 else q - (lo + c * cell)
    return _shrunk(gap, abs(lo) + abs(q) + (abs(c) + 1) * cell)


@compiled
def _query(points: np.ndarray, order: np.ndarray, start: np.ndarray, lo: np.ndarray, cell: float, g: int,
           queries: np.ndarray, rows: np.ndarray, first: int, last: int, k: int, found: np.ndarray,
           dist2: np.ndarray, tied: np.ndarray) -> None:
    """The ``k`` nearest points (ties by index) of ``queries[first:last]`` (each inside the
    grid's box), their squared distances, and whether two of those are equal, into rows
    ``rows[first:last]`` of ``found``, ``dist2`` and ``tied``; ``points`` are sorted by cell
    (``points[s]`` is the input's ``order[s]``).  The query's cell and the 26 around it are
    visited nearest first, and those farther than the k-th point found are skipped; then rings of
    cells farther out until no unvisited cell can hold a nearer point."""
    best_d = np.empty(k)
    best_i = np.empty(k, np.int64)
    c = np.empty(3, np.int64)
    near_d = np.empty(27)
    near_c = np.empty(27, np.int64)
    for i in range(first, last):
        x, y, z = queries[i, 0], queries[i, 1], queries[i, 2]
        for a in range(3):
            c[a] = min(max(int((queries[i, a] - lo[a]) / cell), 0), g - 1)
        m = 0                                               # the occupied cells of the 3x3x3 block, nearest first
        for ox in range(max(c[0] - 1, 0) - c[0], min(c[0] + 1, g - 1) - c[0] + 1):
            gx = _side_gap(x, lo[0], c[0], ox, cell)
            for oy in range(max(c[1] - 1, 0) - c[1], min(c[1] + 1, g - 1) - c[1] + 1):
                gy = _side_gap(y, lo[1], c[1], oy, cell)
                for oz in range(max(c[2] - 1, 0) - c[2], min(c[2] + 1, g - 1) - c[2] + 1):
                    cid = ((c[0] + ox) * g + c[1] + oy) * g + c[2] + oz
                    if start[cid] == start[cid + 1]:
                        continue
                    gz = _side_gap(z, lo[2], c[2], oz, cell)
                    d = gx * gx + gy * gy + gz * gz
                    p = m
                    while p > 0 and near_d[p - 1] > d:
                        near_d[p] = near_d[p - 1]
                        near_c[p] = near_c[p - 1]
                        p -= 1
                    near_d[p] = d
                    near_c[p] = cid
                    m += 1
        n_found = 0
        for q in range(m):
            if n_found == k and near_d[q] > best_d[k - 1]:
                break                                       # this cell and the rest lie beyond the k-th
            n_found = _scan_cell(points, order, start, near_c[q], x, y, z, k, best_d, best_i, n_found)
        r = 1
        scale = abs(lo[0]) + abs(lo[1]) + abs(lo[2]) + abs(x) + abs(y) + abs(z) + g * cell   # the borders' size
        while True:
            # Distance from the query to the outside of the cells visited so far (inf: all of them).
            gap = np.inf
            for a in range(3):
                if c[a] - r > 0:
                    gap = min(gap, queries[i, a] - (lo[a] + (c[a] - r) * cell))
                if c[a] + r < g - 1:
                    gap = min(gap, lo[a] + (c[a] + r + 1) * cell - queries[i, a])
            if gap != np.inf:                               # a point binned across a rounding
                gap = _shrunk(gap, scale)
            if gap == np.inf or (n_found == k and best_d[k - 1] < gap * gap):
                break
            r += 1
            for cx in range(max(c[0] - r, 0), min(c[0] + r, g - 1) + 1):
                for cy in range(max(c[1] - r, 0), min(c[1] + r, g - 1) + 1):
                    for cz in range(max(c[2] - r, 0), min(c[2] + r, g - 1) + 1):
                        if max(abs(cx - c[0]), abs(cy - c[1]), abs(cz - c[2])) != r:
                            continue                        # visited in an earlier ring
                        n_found = _scan_cell(points, order, start, (cx * g + cy) * g + cz, x, y, z, k, best_d,
                                             best_i, n_found)
        tie = False
        row = rows[i]
        for m in range(k):
            if m < found.shape[1]:
                found[row, m] = best_i[m]
            if m < dist2.shape[1]:
                dist2[row, m] = best_d[m]
            if m > 0 and best_d[m] == best_d[m - 1]:
                tie = True
        tied[row] = tie


def nearest(points: np.ndarray, k: int, threads: int = WORKERS) -> np.ndarray:
    """(n, k) int64: the indices of the ``k`` nearest points of each of ``points`` (n, 3) among
    them, as cKDTree gives them (module invariants); 1 <= ``k`` <= n."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = len(pts)
    if not 1 <= k <= n:
        raise ValueError(f"k must be in 1..{n}, got {k}")
    wide = min(k + 1, n)                         # one more: a tie for the last place shows
    found, tied = _grid_nearest(pts, wide, threads, keep=k)
    rows = np.flatnonzero(tied)
    if len(rows) > TIED_SHARE * n:               # a lattice: the tree answers every row at once
        return cKDTree(pts).query(pts, k=k, workers=threads)[1].reshape(n, k).astype(np.int64)
    if len(rows):
        found[rows] = cKDTree(pts).query(pts[rows], k=k, workers=threads)[1].reshape(len(rows), k)
    return found


def nearest_distances(points: np.ndarray, queries: np.ndarray, k: int, threads: int = 1) -> np.ndarray:
    """(m, k): the distances from each of ``queries`` (m, 3), points inside the box of ``points``
    (n, 3), to its ``k`` nearest ``points``, ascending: what ``cKDTree(points).query(queries,
    k)[0]`` gives, bit for bit (distances do not depend on how ties are ordered)."""
    pts = np.ascontiguousarray(points, dtype=np.float64)
    if not 1 <= k <= len(pts):
        raise ValueError(f"k must be in 1..{len(pts)}, got {k}")
    _, dist2, _ = _search(pts, np.ascontiguousarray(queries, dtype=np.float64), k, threads)
    return np.sqrt(dist2)


def _grid_nearest(pts: np.ndarray, k: int, threads: int, keep: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(n, keep) first of the ``k`` nearest (default all k) of each of ``pts`` among them by the grid
    search, ties by index, and (n,) whether a row's k nearest hold a tie (their distances are not kept)."""
    found, _, tied = _search(pts, pts, k, threads, keep, 0)
    return found, tied


def _search(pts: np.ndarray, queries: np.ndarray, k: int, threads: int, keep: int | None = None,
            keep_dist: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The grid search of ``queries`` among ``pts``: (m, keep) indices and (m, keep_dist) squared
    distances, the first of the ``k`` nearest (default all k), and (m,) whether the k hold a tie;
    queries in the order of their cells, on ``threads`` threads."""
    lo, hi = bounding_box(pts)
    extent = float((hi - lo).max())
    cell, g, order, start = _grid(pts, lo, extent, k)
    sorted_pts = pts[order]
    m = len(queries)
    # queries that are the points themselves go in cell order (neighbouring queries, neighbouring memory)
    same = queries is pts
    q, rows = (sorted_pts, order) if same else (queries, np.arange(len(queries)))
    found = np.empty((m, k if keep is None else keep), np.int64)
    dist2 = np.empty((m, k if keep_dist is None else keep_dist))
    tied = np.empty(m, np.bool_)

    def run(a: int, b: int) -> None:
        _query(sorted_pts, order, start, lo, cell, g, q, rows, a, b, k, found, dist2, tied)

    run_parts(run, m, threads)
    return found, dist2, tied


@compiled
def _within(points: np.ndarray, order: np.ndarray, start: np.ndarray, lo: np.ndarray, cell: float, g: int,
            queries: np.ndarray, radius: float, first_only: bool, dist2: np.ndarray, index: np.ndarray,
            tied: np.ndarray) -> None:
    """Per query, the nearest of ``points`` (sorted by cell, ``points[s]`` the input's
    ``order[s]``) nearer than ``radius`` (squared distance below ``radius * radius`` and distance
    below ``radius``): its squared distance (inf: none), index (``len(order)``: none) and whether
    another point lies at the same distance; with ``first_only``, the first found (a hit).  The
    nearest is looked for in the query's own cell first, then in the cells about it that the
    radius reaches, each skipped when no point of it can be as near as the nearest found (its
    distance from the query, shrunk by the rounding margin, above it): the same nearest distance
    and ties, so the same answers where the nearest is unique (a tie is answered by the k-d tree)."""
    n = len(order)
    r2 = radius * radius
    reach = radius * (1.0 + 1e-9) + 1e-300      # the cells a point within the radius can be binned in
    lo_c = np.empty(3, np.int64)
    hi_c = np.empty(3, np.int64)
    own = np.empty(3, np.int64)
    for i in range(len(queries)):
        x, y, z = queries[i, 0], queries[i, 1], queries[i, 2]
        empty = False
        for a in range(3):
            margin = reach + ROUNDING * (abs(queries[i, a]) + abs(lo[a]) + g * cell)
            lo_c[a] = max(int(np.floor((queries[i, a] - margin - lo[a]) / cell)), 0)
            hi_c[a] = min(int(np.floor((queries[i, a] + margin - lo[a]) / cell)), g - 1)
            if lo_c[a] > hi_c[a]:
                empty = True
        best, best_j, tie, done = np.inf, n, False, False
        own_cid = -1                                 # a hit ends the search: no cell is looked at first
        if not empty and not first_only:
            for a in range(3):
                own[a] = min(max(int(np.floor((queries[i, a] - lo[a]) / cell)), lo_c[a]), hi_c[a])
            own_cid = (own[0] * g + own[1]) * g + own[2]
            best, best_j, tie, done = _within_cell(points, order, start, own_cid, x, y, z, r2, radius, first_only,
                                                   best, best_j, tie)
        for cx in range(lo_c[0], hi_c[0] + 1):
            if done or empty:
                break
            for cy in range(lo_c[1], hi_c[1] + 1):
                if done:
                    break
                for cz in range(lo_c[2], hi_c[2] + 1):
                    cid = (cx * g + cy) * g + cz
                    if cid == own_cid:
                        continue
                    if best < np.inf:
                        gap = 0.0
                        for a, c in ((0, cx), (1, cy), (2, cz)):
                            side = _side_gap(queries[i, a], lo[a], own[a], c - own[a], cell)
                            gap += side * side
                        if gap > best:
                            continue
                    best, best_j, tie, done = _within_cell(points, order, start, cid, x, y, z, r2, radius,
                                                           first_only, best, best_j, tie)
                    if done:
                        break
        dist2[i], index[i], tied[i] = best, best_j, tie


@inlined
def _within_cell(points: np.ndarray, order: np.ndarray, start: np.ndarray, cid: int, x: float, y: float, z: float,
                 r2: float, radius: float, first_only: bool, best: float, best_j: int,
                 tie: bool) -> tuple[float, int, bool, bool]:
    """The points of cell ``cid`` offered to :func:`_within`'s nearest so far; and whether it is
    done (``first_only`` and a hit)."""
    for s in range(start[cid], start[cid + 1]):
        dx = x - points[s, 0]
        dy = y - points[s, 1]
        dz = z - points[s, 2]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 >= r2 or not np.sqrt(d2) < radius:
            continue
        if d2 < best:
            best, best_j, tie = d2, order[s], False
            if first_only:
                return best, best_j, tie, True
        elif d2 == best:
            tie = True
    return best, best_j, tie, False


class NeighbourGrid:
    """``points`` (n, 3) on a uniform grid of at most ``CELLS_PER_POINT`` cells per point, for
    queries within a radius (:meth:`hits`, :meth:`nearest`): what ``cKDTree(points).query(q,
    distance_upper_bound=radius)`` answers, bit for bit."""

    def __init__(self, points: np.ndarray) -> None:
        self.points = np.ascontiguousarray(points, dtype=np.float64)
        n = len(self.points)
        self.lo, hi = bounding_box(self.points)
        extent = float((hi - self.lo).max())
        self.g = int(np.clip(np.cbrt(CELLS_PER_POINT * n), 1, MAX_CELLS_PER_AXIS))
        self.cell = extent / self.g if extent > 0 else 1.0
        self.order, self.start = _bucket(self.points, self.lo, self.cell, self.g)
        self.sorted = self.points[self.order]
        self._tree = None

    def _ask(self, queries: np.ndarray, radius: float, first_only: bool):
        q = np.ascontiguousarray(queries, dtype=np.float64)
        dist2, index, tied = np.empty(len(q)), np.empty(len(q), np.int64), np.empty(len(q), np.bool_)
        _within(self.sorted, self.order, self.start, self.lo, self.cell, self.g, q, float(radius), first_only,
                dist2, index, tied)
        return dist2, index, tied

    def hits(self, queries: np.ndarray, radius: float) -> np.ndarray:
        """(m,) bool: whether the k-d tree's nearest distance of each query, asked with
        ``distance_upper_bound=radius``, is below ``radius``."""
        return np.isfinite(self._ask(queries, radius, True)[0])

    def nearest(self, queries: np.ndarray, radius: float) -> tuple[np.ndarray, np.ndarray]:
        """(distances, indices) of each query's nearest point within ``radius``: inf and n where
        none is, as the k-d tree gives them; queries whose nearest is tied are asked of it."""
        dist2, index, tied = self._ask(queries, radius, False)
        dist = np.sqrt(dist2)
        if tied.any():
            rows = np.flatnonzero(tied)
            if self._tree is None:
                self._tree = cKDTree(self.points)
            dist[rows], index[rows] = self._tree.query(np.asarray(queries)[rows], distance_upper_bound=radius)
        return dist, index
