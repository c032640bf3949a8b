"""Compiled kernels of normal estimation (numba): the covariance of each point's neighbourhood and
Hoppe et al.'s orientation, signs propagated along a minimum spanning tree of the k-nearest-
neighbour graph.  NumPy cannot express the tree's union-find and breadth-first walk without a
Python loop per point; these run them compiled (cached on disk after the first call).

Invariants: every function is a pure function of its arrays; :func:`covariances` sums in the
neighbours' order as NumPy does, :func:`spanning_tree` takes edges in the order given (ascending
weight: :func:`edges_by_weight`), and :func:`propagate_signs` walks from the lowest-numbered point
of each connected part.
The graph's edges, their weights and their order are those SciPy's ``minimum_spanning_tree``
took (the symmetric matrix's data in CSR order, stably sorted), less each pair's second entry,
which Kruskal's walk rejects (:func:`neighbour_graph`), so the tree and the normals are SciPy's
bit for bit, on clouds with many tied weights too.
"""

from __future__ import annotations

import sys

import numpy as np

from .jit import compiled
from .parallel import run_parts


@compiled
def _pairwise(x: np.ndarray, n: int) -> float:
    """The sum of ``x[:n]`` in NumPy's order for a contiguous reduction (pairwise: below 8
    values one by one; up to 128, eight running sums combined as a tree, the rest one by one)."""
    if n < 8:
        total = 0.0
        for i in range(n):
            total += x[i]
        return total
    r = x[:8].copy()
    i = 8
    while i < n - n % 8:
        for j in range(8):
            r[j] += x[i + j]
        i += 8
    total = ((r[0] + r[1]) + (r[2] + r[3])) + ((r[4] + r[5]) + (r[6] + r[7]))
    while i < n:
        total += x[i]
        i += 1
    return total


def covariances(points: np.ndarray, nn: np.ndarray) -> np.ndarray:
    """(6, n): xx, xy, xz, yy, yz, zz of the covariance (divided by k) of each point's ``nn`` (n, k)
    neighbours ``points[nn[i]]`` about their mean, summed in the order NumPy sums
    ``nb.mean(1)`` (one by one) and ``(d[..., a] * d[..., b]).mean(1)`` (:func:`_pairwise`): the
    same bits as that NumPy expression.  Rows are shared between the cores."""
    out = np.empty((6, len(nn)))
    run_parts(lambda a, b: covariance_rows(points, nn, a, b, out), len(nn))
    return out


@compiled
def covariance_rows(points: np.ndarray, nn: np.ndarray, first: int, last: int, out: np.ndarray) -> None:
    """Columns ``first:last`` of :func:`covariances`, written into ``out``."""
    k = nn.shape[1]
    d = np.empty((3, k))
    prod = np.empty(k)
    pairs = ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))
    for i in range(first, last):
        for a in range(3):
            m = 0.0
            for j in range(k):
                m += points[nn[i, j], a]
            m /= k
            for j in range(k):
                d[a, j] = points[nn[i, j], a] - m
        for c in range(6):
            a, b = pairs[c]
            for j in range(k):
                prod[j] = d[a, j] * d[b, j]
            out[c, i] = _pairwise(prod, k) / k


@compiled
def _root(parent: np.ndarray, i: int) -> int:
    while parent[i] != i:
        parent[i] = parent[parent[i]]            # path halving
        i = parent[i]
    return i


@compiled
def _weight(normals: np.ndarray, i: int, j: int) -> float:
    """1 - |n_i . n_j| + 1e-6: the same bits for (i, j) and (j, i)."""
    dot = normals[i, 0] * normals[j, 0] + normals[i, 1] * normals[j, 1] + normals[i, 2] * normals[j, 2]
    return 1.0 - abs(dot) + 1e-6


@compiled
def neighbour_graph(nn: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The k-nearest-neighbour graph made undirected, as the rows, columns and weights
    (:func:`_weight`) of the upper triangle of its symmetric sparse matrix in canonical CSR order
    (rows ascending, each row's columns ascending, every pair once, ``row < col``): point ``i``
    joins its neighbours ``nn[i, 1:]`` (``nn[i, 0]`` is ``i`` itself) and the points that have
    ``i`` among theirs.  Kruskal's walk over the whole symmetric matrix in stably sorted order
    meets each pair's lower entry after its upper one, with the same weight, and rejects it; the
    upper triangle alone gives the same tree with half the edges to sort."""
    n, k = nn.shape
    # every directed edge i -> nn[i, j] filed under the lower of its two ends: row i holds first its
    # own neighbours above i (in neighbour order), then the points above i that have i among theirs
    # (ascending, as they are filed in point order)
    count = np.zeros(n + 1, np.int64)
    own = np.zeros(n, np.int64)
    for i in range(n):
        for j in range(1, k):
            t = nn[i, j]
            if t != i:
                count[min(i, t) + 1] += 1
                if t > i:
                    own[i] += 1
    start = np.cumsum(count)
    fill = start[:-1].copy()
    upper = np.empty(start[n], np.int64)
    for i in range(n):
        for j in range(1, k):
            t = nn[i, j]
            if t != i:
                low = min(i, t)
                upper[fill[low]] = max(i, t)
                fill[low] += 1
    rows = np.empty(start[n], np.int64)
    cols = np.empty_like(rows)
    m = 0
    for i in range(n):
        a, mid, b = start[i], start[i] + own[i], start[i + 1]
        for r in range(a + 1, mid):            # insertion sort of the own part (at most k - 1 entries)
            v, q = upper[r], r
            while q > a and upper[q - 1] > v:
                upper[q] = upper[q - 1]
                q -= 1
            upper[q] = v
        p, q, last = a, mid, -1                # merge the two ascending parts, each pair once
        while p < mid or q < b:
            if q >= b or (p < mid and upper[p] <= upper[q]):
                v = upper[p]
                p += 1
            else:
                v = upper[q]
                q += 1
            if v != last:
                rows[m], cols[m] = i, v
                m += 1
                last = v
    weights = np.empty(m)
    for e in range(m):
        weights[e] = _weight(normals, rows[e], cols[e])
    return rows[:m], cols[:m], weights


def edges_by_weight(weights: np.ndarray, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The edges ``a[e]``-``b[e]`` (node numbers below 2^32) in the order of
    ``np.argsort(weights, kind="stable")`` of non-negative weights (whose bit patterns order as the
    floats do): the order, ties included, SciPy's Kruskal takes them in.  The pairs travel with the
    keys through the radix passes (:func:`sorted_payloads`), so that the tree reads them in turn
    instead of looking each up through a permutation (a cache miss an edge on large clouds)."""
    a, b = np.ascontiguousarray(a, dtype=np.int64), np.ascontiguousarray(b, dtype=np.int64)
    ends = _edges_by_weight(np.ascontiguousarray(weights, dtype=np.float64).view(np.uint64), a, b)
    ends = ends.view(np.uint32).reshape(-1, 2)             # each edge's two 32-bit halves, read in place
    return (ends[:, 1], ends[:, 0]) if sys.byteorder == "little" else (ends[:, 0], ends[:, 1])


@compiled
def _edges_by_weight(keys: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """:func:`edges_by_weight` of the weights' bit patterns: each edge's ends packed in one 64-bit
    payload (``a`` above ``b``), in the sorted order; ValueError for a node number outside 32 bits
    (checked as the ends are packed)."""
    packed = np.empty(len(keys), np.uint64)
    for e in range(len(keys)):
        if a[e] < 0 or b[e] < 0 or a[e] >= 1 << 32 or b[e] >= 1 << 32:
            raise ValueError("edges_by_weight packs node numbers in 32 bits: they must lie in 0 .. 2^32 - 1")
        packed[e] = (np.uint64(a[e]) << np.uint64(32)) | np.uint64(b[e])
    return sorted_payloads(keys, packed)


@compiled
def radix_order(keys: np.ndarray) -> np.ndarray:
    """``np.argsort(keys, kind="stable")`` of uint64 keys (:func:`sorted_payloads` carrying each
    key's index)."""
    return sorted_payloads(keys, np.arange(len(keys)).view(np.uint64)).view(np.int64)


DIGIT_BITS = 8
"""Bits of a radix pass: 256 buckets, whose write positions stay in the cache (16-bit digits, 4
passes, were twice as slow on 1.6 million keys for their 65,536 scattered positions)."""


@compiled
def sorted_payloads(keys: np.ndarray, payloads: np.ndarray) -> np.ndarray:
    """``payloads[np.argsort(keys, kind="stable")]`` of uint64 keys and payloads: a least-significant-
    digit radix sort, :data:`DIGIT_BITS` bits a pass, each key moving with its payload; the
    histograms of every pass counted in one reading of the keys, and a pass where every key has
    the same digit skipped (it would move nothing).  ``keys`` is not written; ``payloads`` is the
    sort's work space (its contents are lost): the callers make it for the sort."""
    n = len(keys)
    buckets = 1 << DIGIT_BITS
    passes = (64 + DIGIT_BITS - 1) // DIGIT_BITS
    mask = buckets - 1
    hist = np.zeros((passes, buckets), np.int64)
    for i in range(n):
        k = keys[i]
        for p in range(passes):
            hist[p, (k >> (p * DIGIT_BITS)) & mask] += 1
    src_k, src_p = keys, payloads                # read in place by the first pass that moves anything
    dst_k, dst_p = np.empty_like(keys), np.empty_like(payloads)
    first = True
    offset = np.empty(buckets, np.int64)
    for p in range(passes):
        total = 0
        moves = True
        for d in range(buckets):
            moves = moves and hist[p, d] != n
            offset[d] = total
            total += hist[p, d]
        if not moves:
            continue
        shift = p * DIGIT_BITS
        for j in range(n):
            k = src_k[j]
            d = (k >> shift) & mask
            dst_k[offset[d]] = k
            dst_p[offset[d]] = src_p[j]
            offset[d] += 1
        if first:                                # then two buffers of each, in turn: keys are not written
            first = False
            src_k, src_p, dst_k, dst_p = dst_k, dst_p, np.empty_like(keys), payloads
        else:
            src_k, src_p, dst_k, dst_p = dst_k, dst_p, src_k, src_p
    return src_p


@compiled
def spanning_tree(n: int, a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Kruskal's minimum spanning forest of ``n`` nodes (fewer than 2^31: its union-find is 32-bit):
    the edges ``a[e]``-``b[e]`` taken in turn (ascending weight: :func:`edges_by_weight`); returns
    the forest's edges (two arrays)."""
    if n >= 1 << 31:
        raise ValueError("spanning_tree takes fewer than 2^31 nodes")
    parent = np.arange(n).astype(np.int32)
    size = np.ones(n, np.int32)
    ta = np.empty(max(n - 1, 0), np.int64)
    tb = np.empty(max(n - 1, 0), np.int64)
    m = 0
    for e in range(len(a)):
        u, v = a[e], b[e]
        ra, rb = _root(parent, u), _root(parent, v)
        if ra == rb:
            continue
        if size[ra] < size[rb]:
            ra, rb = rb, ra
        parent[rb] = ra
        size[ra] += size[rb]
        ta[m], tb[m] = u, v
        m += 1
        if m == n - 1:
            break
    return ta[:m], tb[:m]


@compiled
def propagate_signs(n: int, ta: np.ndarray, tb: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Signs (n,) making ``normals`` consistent along the forest ``ta``-``tb`` (a node's sign is
    its tree parent's, negated where their normals point apart), walked breadth first from the
    lowest-numbered node of each part (sign +1); and each node's part number (0, 1, ...)."""
    degree = np.zeros(n + 1, np.int64)
    for e in range(len(ta)):
        degree[ta[e] + 1] += 1
        degree[tb[e] + 1] += 1
    start = np.cumsum(degree)
    fill = start[:-1].copy()
    adjacent = np.empty(2 * len(ta), np.int64)
    for e in range(len(ta)):
        adjacent[fill[ta[e]]] = tb[e]
        fill[ta[e]] += 1
        adjacent[fill[tb[e]]] = ta[e]
        fill[tb[e]] += 1
    sign = np.zeros(n)
    part = np.full(n, -1, np.int64)
    queue = np.empty(n, np.int64)
    parts = 0
    for root in range(n):
        if part[root] >= 0:
            continue
        sign[root], part[root] = 1.0, parts
        head, tail = 0, 1
        queue[0] = root
        while head < tail:
            v = queue[head]
            head += 1
            for s in range(start[v], start[v + 1]):
                w = adjacent[s]
                if part[w] >= 0:
                    continue
                dot = normals[v, 0] * normals[w, 0] + normals[v, 1] * normals[w, 1] + normals[v, 2] * normals[w, 2]
                sign[w] = -sign[v] if dot < 0 else sign[v]
                part[w] = parts
                queue[tail] = w
                tail += 1
        parts += 1
    return sign, part
