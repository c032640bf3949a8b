"""Compiled helpers on graphs and point sets (numba): the connected parts of a graph (union-find,
numbered as SciPy numbers them) and the pairs of points closer than a radius (a hash grid, for
the tiny radii at which a welding reader merges vertices)."""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from ..octree.jit import compiled

CELL = 1024
"""The hash grid's cell, in radii: a point near none of its cell's sides (almost every point, the
radius being tiny) looks in its own cell only."""


def components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) int64: the connected part of each of ``n`` nodes joined by the edges ``a``-``b``,
    numbered 0, 1, ... in the order of their lowest node (as SciPy's ``connected_components``
    numbers them), by union-find."""
    return _components(int(n), np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64))


@compiled
def _components(n: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    parent = np.arange(n)
    for e in range(len(a)):
        ra, rb = a[e], b[e]
        while parent[ra] != ra:
            parent[ra] = parent[parent[ra]]
            ra = parent[ra]
        while parent[rb] != rb:
            parent[rb] = parent[parent[rb]]
            rb = parent[rb]
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)          # the root is the part's lowest node
    label = np.empty(n, np.int64)
    count = 0
    for i in range(n):
        r = i
        while parent[r] != r:
            r = parent[r]
        if r == i:
            label[i] = count
            count += 1
        else:
            label[i] = label[r]
    return label


def close_pairs(points: np.ndarray, radius: float) -> np.ndarray:
    """(P, 2) int64: every pair ``i < j`` of ``points`` (N, 3) at most ``radius`` apart (as
    ``cKDTree.query_pairs`` finds them, in another order)."""
    points = np.ascontiguousarray(points, dtype=np.float64)
    if len(points) < 2 or not radius > 0:
        return np.zeros((0, 2), np.int64)
    cell = float(radius) * CELL
    if not np.abs(points).max() / cell < 2.0 ** 52:             # cells beyond 64-bit integers: the k-d tree
        return cKDTree(points).query_pairs(radius, output_type="ndarray").astype(np.int64)
    return _close_pairs(points, float(radius), cell)


@compiled
def _hash(x: int, y: int, z: int) -> int:
    return (x * 73856093) ^ (y * 19349663) ^ (z * 83492791)


@compiled
def _close_pairs(points: np.ndarray, radius: float, cell: float) -> np.ndarray:
    n = len(points)
    q = np.floor(points / cell).astype(np.int64)
    key = np.empty(n, np.int64)
    for i in range(n):
        key[i] = _hash(q[i, 0], q[i, 1], q[i, 2])
    order = np.argsort(key)
    sorted_key = key[order]
    out = np.empty((16, 2), np.int64)
    found = 0
    reach, r2 = 2.0 * radius, radius * radius
    lo = np.empty(3, np.int64)
    hi = np.empty(3, np.int64)
    for i in range(n):
        for a in range(3):                      # the neighbouring cells within reach, per axis
            inner = points[i, a] - q[i, a] * cell
            lo[a] = -1 if inner <= reach else 0
            hi[a] = 1 if cell - inner <= reach else 0
        for dx in range(lo[0], hi[0] + 1):
            for dy in range(lo[1], hi[1] + 1):
                for dz in range(lo[2], hi[2] + 1):
                    cx, cy, cz = q[i, 0] + dx, q[i, 1] + dy, q[i, 2] + dz
                    h = _hash(cx, cy, cz)
                    k = np.searchsorted(sorted_key, h)
                    while k < n and sorted_key[k] == h:
                        j = order[k]
                        k += 1
                        if j <= i or q[j, 0] != cx or q[j, 1] != cy or q[j, 2] != cz:
                            continue
                        d = points[i] - points[j]
                        if d[0] * d[0] + d[1] * d[1] + d[2] * d[2] <= r2:
                            if found == len(out):
                                out = np.concatenate((out, np.empty_like(out)))
                            out[found, 0], out[found, 1] = i, j
                            found += 1
    return out[:found]
