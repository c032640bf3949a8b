"""A completed shape fused with the scan it came from: what the scan saw keeps the scan's patches.

A completion network fills what a scan misses, but re-draws what the scan saw at its own
resolution and with its own errors.  :func:`keep_scan` takes the scan's patches wherever the scan
saw the shape and the network's patches everywhere else, and returns one octree of both, so the
patches, the closed surface and every mesh format work on it unchanged.

Where one tree has a leaf and the other is split, the leaf is refined: it is cut into the eight
children of its octant, each keeping the leaf's plane where the plane crosses it, until the two
trees agree or the finest depth is reached.  So a network leaf the scan saw a corner of keeps its
patch everywhere the scan has no points, and a coarse scan leaf (whose patch the scan covers: its
fitting error is below the threshold) keeps the network's leaves away from its plane: the surfaces
the scan did not see inside that octant.

The fusion walks both trees at once, depth first over the octants either tree splits (compiled
with numba: a NumPy formulation, one level of both trees at a time, spent 16-24 ms of a
completion request on a 20,000-point scan, the walk 4 ms); its arithmetic is NumPy's, operation
for operation, and tests compare every leaf with that formulation bit for bit.  The fused tree is
then built from its leaves level by level, each level in one compiled pass (tests compare every
level's arrays with the NumPy construction).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .jit import compiled, inlined
from .neighbors import build_neighbors
from .octree import EMPTY, LEAF, PLANE_SCALE, SPLIT, Octree, OctreeLevel

_CLAIMED = 3
"""A side's state in an octant its plane passes near but does not cross: no patch, but the other
side's leaves there are dropped (they draw the same surface)."""


@dataclass(frozen=True)
class _Flat:
    """One tree's levels up to a depth as flat arrays: node ``r`` of depth ``d`` is row
    ``start[d] + r`` of ``label``, ``child`` (int64), ``live`` (:func:`_live`), ``plane``,
    ``error`` and ``npoints``."""

    start: np.ndarray
    label: np.ndarray
    child: np.ndarray
    live: np.ndarray
    plane: np.ndarray
    error: np.ndarray
    npoints: np.ndarray


def _flat(tree: Octree, depth: int) -> _Flat:
    """``tree``'s levels 0..``depth`` flattened for the compiled walk (:class:`_Flat`)."""
    levels = tree.levels[:depth + 1]
    start = np.concatenate([[0], np.cumsum([len(lv) for lv in levels])]).astype(np.int64)
    return _Flat(start, np.concatenate([lv.label for lv in levels]),
                 np.concatenate([lv.child for lv in levels]).astype(np.int64),
                 np.concatenate(_live(tree, depth)), np.concatenate([lv.plane for lv in levels]),
                 np.concatenate([lv.error for lv in levels]), np.concatenate([lv.npoints for lv in levels]))


def keep_scan(decoded: Octree, scan: Octree, neighbors: bool = False) -> Octree:
    """The octree of ``scan``'s patches where the scan saw the shape and ``decoded``'s elsewhere.

    Both are single-shape octrees in the same cube (the scan's frame: a completion model decodes
    there), with keys without batch bits.  ``scan`` may be deeper than ``decoded``: its non-empty
    octants at ``decoded.depth`` then count as leaves with their fitted planes.  An octant where
    both trees have a leaf keeps the scan's; where one has a leaf and the other is split, the leaf
    is refined (module docstring).  A decoded patch is dropped where the scan has points at its
    octant or the scan's plane passes within the scan's threshold of it.  The result keeps
    ``decoded``'s depth, full and adaptive depths, threshold and frame (normalization); its leaves
    never nest (invariant of an octree) and every scan patch's surface is kept.
    """
    if decoded.batch_size != 1 or scan.batch_size != 1:
        raise ValueError("keep_scan takes single-shape octrees (split batches first)")
    if scan.depth < decoded.depth:
        raise ValueError(f"the scan's octree (depth {scan.depth}) is shallower than the output ({decoded.depth})")
    depth = decoded.depth
    s, o = _flat(scan, depth), _flat(decoded, depth)
    at, key, plane, error, npoints = _walk(depth, float(scan.threshold), s.start, s.label, s.child, s.live, s.plane,
                                           s.error, s.npoints, o.start, o.label, o.child, o.live, o.plane,
                                           o.error, o.npoints)
    return _from_leaves(decoded, at, key, plane, error, npoints, neighbors)


def _live(tree: Octree, depth: int) -> list[np.ndarray]:
    """Per level up to ``depth``: whether each node holds a patch, its own (a leaf, or any
    non-empty node at ``depth``) or a descendant's."""
    live = [None] * (depth + 1)
    live[depth] = tree.levels[depth].label != EMPTY
    for d in range(depth - 1, -1, -1):
        lv = tree.levels[d]
        split = lv.child >= 0
        below = np.zeros(len(lv), bool)
        below[split] = live[d + 1].reshape(-1, 8).any(1)[lv.child[split]]
        live[d] = (lv.label == LEAF) | below
    return live


@inlined
def _centre_dot(n0: float, n1: float, n2: float, x: int, y: int, z: int, size: float) -> float:
    """``n . c`` for the centre ``c`` of octant ``x, y, z`` of edge ``size``, in NumPy's order
    (``(n * ((xyz + 0.5) * size)).sum(1)``: left to right)."""
    return (n0 * ((x + 0.5) * size) + n1 * ((y + 0.5) * size)) + n2 * ((z + 0.5) * size)


@inlined
def _node_state(d: int, r: int, x: int, y: int, z: int, last: bool, start, label, live, plane):
    """A tree's own node ``r`` of depth ``d`` (octant ``x, y, z``) as a side's state (kind, row,
    source depth, source row, the unit normal and ``normal . x`` of a leaf's plane, zeros
    otherwise); at the output's ``last`` depth every non-empty node is a leaf.  Arithmetic in
    NumPy's order: the normal divided by its norm (at least 1e-12), the level ``n . c - d*
    sqrt(3)/2 h``."""
    g = start[d] + r
    kind = np.int64(label[g]) if live[g] else EMPTY
    if last and kind != EMPTY:
        kind = LEAF
    if kind != LEAF:
        return kind, r, d, r, 0.0, 0.0, 0.0, 0.0
    n0, n1, n2 = np.float64(plane[g, 0]), np.float64(plane[g, 1]), np.float64(plane[g, 2])
    norm = max(np.sqrt(n0 * n0 + n1 * n1 + n2 * n2), 1e-12)
    n0, n1, n2 = n0 / norm, n1 / norm, n2 / norm
    size = 1.0 / (1 << d)
    level = _centre_dot(n0, n1, n2, x, y, z, size) - np.float64(plane[g, 3]) * PLANE_SCALE * size
    return kind, r, d, r, n0, n1, n2, level


@inlined
def _child_state(d: int, slot: int, x: int, y: int, z: int, last: bool, tolerance: float, start, label, child,
                 live, plane, kind: int, row: int, sd: int, sr: int, n0: float, n1: float, n2: float, level: float):
    """The state of child ``slot`` (octant ``x, y, z`` at depth ``d + 1``) of a side's octant at
    depth ``d`` in state (``kind`` ... ``level``): a split node's child is its own node; a leaf's
    (or claimed) plane passes to the child it crosses as a leaf, to one within ``tolerance`` of it
    (negative: none) as claimed, elsewhere the child is empty."""
    if kind == SPLIT:
        return _node_state(d + 1, child[start[d] + row] * 8 + slot, x, y, z, last, start, label, live, plane)
    out = EMPTY
    if kind == LEAF or kind == _CLAIMED:
        size = 1.0 / (1 << (d + 1))
        gap = abs(_centre_dot(n0, n1, n2, x, y, z, size) - level)
        reach = 0.5 * size * ((abs(n0) + abs(n1)) + abs(n2))
        if gap <= reach:
            out = _CLAIMED if kind == _CLAIMED else LEAF
        elif tolerance >= 0 and gap <= reach + tolerance:
            out = _CLAIMED
    return out, np.int64(-1), sd, sr, n0, n1, n2, level


@inlined
def _emit(m: int, d: int, key, x: int, y: int, z: int, row: int, sd: int, sr: int, n0: float, n1: float,
          n2: float, level: float, start, plane, error, npoints, at, keys, planes, errors, counts) -> None:
    """Leaf ``m`` of the result at depth ``d`` from a side's state: a node's own row as it is; a
    plane refined from a coarser leaf re-expressed for its octant, with the error of the leaf it
    came from (depth ``sd``, row ``sr``) and no point count."""
    at[m], keys[m] = d, key
    if row >= 0:
        g = start[d] + row
        for c in range(4):
            planes[m, c] = plane[g, c]
        errors[m], counts[m] = error[g], npoints[g]
        return
    size = 1.0 / (1 << d)
    offset = _centre_dot(n0, n1, n2, x, y, z, size) - level
    planes[m, 0], planes[m, 1], planes[m, 2] = n0, n1, n2
    planes[m, 3] = offset / (PLANE_SCALE * size)
    errors[m], counts[m] = error[start[sd] + sr], 0


@compiled
def _walk(depth: int, tolerance: float, s_start, s_label, s_child, s_live, s_plane, s_error, s_npoints,
          o_start, o_label, o_child, o_live, o_plane, o_error, o_npoints):
    """The leaves of :func:`keep_scan`'s result, walked depth first over the octants either tree
    splits: (depth, key, plane, error, point count) per leaf.  A side's state: kind, row (-1
    inside a leaf of its tree), the (depth, row) of the leaf its plane comes from, and that
    leaf's unit normal and ``normal . x`` (cube units); the stack holds (depth, x, y, z, key) and
    both sides' states per octant."""
    cap = 1024
    at = np.empty(cap, np.int64)
    keys = np.empty(cap, np.uint64)
    planes = np.empty((cap, 4), np.float32)
    errors = np.empty(cap, np.float32)
    counts = np.empty(cap, np.int32)
    m = 0
    top = 8 * (depth + 1) + 1
    si = np.empty((top, 8), np.int64)           # d, x, y, z, then the scan's kind, row, sd, sr
    sf = np.empty((top, 4))                     # the scan's n0, n1, n2, level
    sk = np.empty(top, np.uint64)
    last = depth == 0
    si[0, :4] = 0
    si[0, 4], si[0, 5], si[0, 6], si[0, 7], sf[0, 0], sf[0, 1], sf[0, 2], sf[0, 3] = \
        _node_state(0, 0, 0, 0, 0, last, s_start, s_label, s_live, s_plane)
    ok, orow, osd, osr, on0, on1, on2, olev = _node_state(0, 0, 0, 0, 0, last, o_start, o_label, o_live, o_plane)
    sk[0] = 0
    o_i = np.empty((top, 4), np.int64)          # the output's kind, row, sd, sr
    o_f = np.empty((top, 4))                    # the output's n0, n1, n2, level
    o_i[0, 0], o_i[0, 1], o_i[0, 2], o_i[0, 3] = ok, orow, osd, osr
    o_f[0, 0], o_f[0, 1], o_f[0, 2], o_f[0, 3] = on0, on1, on2, olev
    n = 1
    while n > 0:
        n -= 1
        d, x, y, z, key = si[n, 0], si[n, 1], si[n, 2], si[n, 3], sk[n]
        sK, sR, sSD, sSR = si[n, 4], si[n, 5], si[n, 6], si[n, 7]
        s0, s1, s2, sL = sf[n, 0], sf[n, 1], sf[n, 2], sf[n, 3]
        oK, oR, oSD, oSR = o_i[n, 0], o_i[n, 1], o_i[n, 2], o_i[n, 3]
        o0, o1, o2, oL = o_f[n, 0], o_f[n, 1], o_f[n, 2], o_f[n, 3]
        if m + 1 > cap:                                    # an octant emits at most one leaf
            cap *= 2
            at, keys, planes = _grown(at, cap), _grown(keys, cap), _grown(planes, cap)
            errors, counts = _grown(errors, cap), _grown(counts, cap)
        if sK == LEAF and (oK != SPLIT or d == depth):
            _emit(m, d, key, x, y, z, sR, sSD, sSR, s0, s1, s2, sL, s_start, s_plane, s_error, s_npoints,
                  at, keys, planes, errors, counts)
            m += 1
        if oK == LEAF and sK == EMPTY:
            _emit(m, d, key, x, y, z, oR, oSD, oSR, o0, o1, o2, oL, o_start, o_plane, o_error, o_npoints,
                  at, keys, planes, errors, counts)
            m += 1
        if d == depth or not (sK == SPLIT or oK == SPLIT):
            continue
        last = d + 1 == depth
        for slot in range(7, -1, -1):                      # slot 0 on top: visited first
            cx, cy, cz = 2 * x + (slot >> 2), 2 * y + ((slot >> 1) & 1), 2 * z + (slot & 1)
            si[n, 0], si[n, 1], si[n, 2], si[n, 3] = d + 1, cx, cy, cz
            sk[n] = (key << np.uint64(3)) | np.uint64(slot)
            si[n, 4], si[n, 5], si[n, 6], si[n, 7], sf[n, 0], sf[n, 1], sf[n, 2], sf[n, 3] = _child_state(
                d, slot, cx, cy, cz, last, tolerance, s_start, s_label, s_child, s_live, s_plane,
                sK, sR, sSD, sSR, s0, s1, s2, sL)
            o_i[n, 0], o_i[n, 1], o_i[n, 2], o_i[n, 3], o_f[n, 0], o_f[n, 1], o_f[n, 2], o_f[n, 3] = _child_state(
                d, slot, cx, cy, cz, last, -1.0, o_start, o_label, o_child, o_live, o_plane,
                oK, oR, oSD, oSR, o0, o1, o2, oL)
            n += 1
    return at[:m], keys[:m], planes[:m], errors[:m], counts[:m]


@compiled
def _grown(a, cap: int):
    """``a`` copied into a longer array of ``cap`` rows."""
    out = np.empty((cap,) + a.shape[1:], a.dtype)
    out[:len(a)] = a
    return out


def _from_leaves(like: Octree, at: np.ndarray, key: np.ndarray, plane: np.ndarray, error: np.ndarray,
                 npoints: np.ndarray, neighbors: bool) -> Octree:
    """The octree whose leaves are the given ones (depth ``at``, ``key``, ``plane``, ``error``,
    ``npoints`` per leaf; each depth's keys ascending, as the walk emits them; the keys of all
    depths cover disjoint regions): every ancestor of a leaf split (with all 8 children), every
    node above ``like.full_depth`` split, everything else empty; ``like``'s depth, settings and
    frame.  Level by level from the root, each in one compiled pass (:func:`_fill_level`) over
    arrays of its exact size."""
    depth = like.depth
    order, first, unsorted = _by_depth(depth, at, key)
    if unsorted >= 0:
        raise ValueError(f"depth {unsorted}: the leaves' keys are not ascending")
    levels: list[OctreeLevel] = []
    keys, parent = np.zeros(1, np.uint64), np.full(1, -1, np.int32)
    for d in range(depth + 1):
        n = len(keys)
        lv = OctreeLevel(depth=d, key=keys, label=np.full(n, EMPTY, np.int8), child=np.full(n, -1, np.int32),
                         parent=parent, plane=np.zeros((n, 4), np.float32), error=np.full(n, np.nan, np.float32),
                         npoints=np.zeros(n, np.int32))
        code, keys, parent = _fill_level(d, depth, like.full_depth, order, first, key, plane, error, npoints,
                                         lv.key, lv.label, lv.child, lv.plane, lv.error, lv.npoints)
        if code == 1:
            raise ValueError(f"depth {d}: leaves nest or lie outside the tree")
        if code == 2:
            raise ValueError(f"depth {d}: a leaf contains another leaf")
        levels.append(lv)
    fused = Octree(depth=depth, levels=levels, adaptive=True, threshold=like.threshold,
                   full_depth=like.full_depth, adaptive_depth=like.adaptive_depth,
                   normalizations=list(like.normalizations))
    if neighbors:
        build_neighbors(fused)
    return fused


@compiled
def _by_depth(depth: int, at, key):
    """The leaves grouped by depth, stably: (order, first: where each depth's leaves start in
    ``order``, the first depth whose keys are not ascending or -1)."""
    first = np.zeros(depth + 2, np.int64)
    for i in range(len(at)):
        first[at[i] + 1] += 1
    for d in range(depth + 1):
        first[d + 1] += first[d]
    order = np.empty(len(at), np.int64)
    fill = first[:depth + 1].copy()
    for i in range(len(at)):
        order[fill[at[i]]] = i
        fill[at[i]] += 1
    for d in range(depth + 1):
        for j in range(first[d] + 1, first[d + 1]):
            if key[order[j]] <= key[order[j - 1]]:
                return order, first, d
    return order, first, -1


@compiled
def _fill_level(d: int, depth: int, full_depth: int, order, first, key, plane, error, npoints,
                keys, label, child, planes, errors, counts):
    """Level ``d`` of :func:`_from_leaves` (its ascending ``keys``; the other arrays empty, written
    here): its leaves found among its keys; a node split when it is above the full depth or an
    ancestor of a deeper leaf (each deeper depth's leaves, shifted to this depth, are walked
    beside the ascending keys).  Returns (code: 0, 1 a leaf not among the keys, 2 a leaf that is
    split; the next level's keys, the children of the splits in order; their parents' rows)."""
    n = len(keys)
    r = 0
    for j in range(first[d], first[d + 1]):
        leaf = order[j]
        while r < n and keys[r] < key[leaf]:
            r += 1
        if r == n or keys[r] != key[leaf]:
            return 1, np.zeros(0, np.uint64), np.zeros(0, np.int32)
        label[r] = LEAF
        for c in range(4):
            planes[r, c] = plane[leaf, c]
        errors[r], counts[r] = error[leaf], npoints[leaf]
    if d == depth:
        return 0, np.zeros(0, np.uint64), np.zeros(0, np.int32)
    at = first[d + 1:depth + 1].copy()                      # a pointer into each deeper depth's leaves
    split = 0
    for r in range(n):
        below = d < full_depth
        for e in range(d + 1, depth + 1):
            shift = np.uint64(3 * (e - d))
            while at[e - d - 1] < first[e + 1] and key[order[at[e - d - 1]]] >> shift < keys[r]:
                at[e - d - 1] += 1
            if at[e - d - 1] < first[e + 1] and key[order[at[e - d - 1]]] >> shift == keys[r]:
                below = True
        if below:
            if label[r] == LEAF:
                return 2, np.zeros(0, np.uint64), np.zeros(0, np.int32)
            label[r] = SPLIT
            child[r] = split
            split += 1
    nxt = np.empty(8 * split, np.uint64)
    parent = np.empty(8 * split, np.int32)
    m = 0
    for r in range(n):
        if label[r] == SPLIT:
            for slot in range(8):
                nxt[m] = (keys[r] << np.uint64(3)) | np.uint64(slot)
                parent[m] = r
                m += 1
    return 0, nxt, parent
