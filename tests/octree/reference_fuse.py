"""The scan fusion as first written: NumPy, one level of both trees at a time.

A deliberately plain second implementation of ``model.octree.fuse.keep_scan`` (the formulation
before the fusion's walk was compiled), kept so that tests can check that the compiled walk
gives every leaf the same plane, error and point count, bit for bit; and the construction of the
fused tree from its leaves (:func:`reference_tree`), kept to check the compiled one.  It shares only the
octree's data structure, Morton keys and which nodes hold a patch (``_live``) with the module.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from model.octree import keys as morton
from model.octree.fuse import _live
from model.octree.octree import EMPTY, LEAF, PLANE_SCALE, SPLIT, Octree, OctreeLevel

_CLAIMED = np.int8(3)
"""A side's state in an octant its plane passes near but does not cross: no patch, but the other
side's leaves there are dropped (they draw the same surface)."""


@dataclass
class _Side:
    """One tree's state over a list of octants of one depth: ``kind`` EMPTY / SPLIT / LEAF /
    _CLAIMED; ``row`` the octant's node in the tree's level (-1 for an octant inside a leaf of
    the tree); ``normal`` (unit) and ``level`` (``normal . x``, cube units) the leaf's plane;
    ``source`` the (depth, row) of the leaf the plane comes from, for its error."""

    kind: np.ndarray
    row: np.ndarray
    normal: np.ndarray
    level: np.ndarray
    source: np.ndarray

    def take(self, sel: np.ndarray) -> _Side:
        return _Side(self.kind[sel], self.row[sel], self.normal[sel], self.level[sel], self.source[sel])


def reference_leaves(decoded: Octree, scan: Octree) -> dict:
    """{(depth, key): (plane bytes, error bytes, point count)} of every leaf of the fusion."""
    if decoded.batch_size != 1 or scan.batch_size != 1:
        raise ValueError("keep_scan takes single-shape octrees (split batches first)")
    if scan.depth < decoded.depth:
        raise ValueError(f"the scan's octree (depth {scan.depth}) is shallower than the output ({decoded.depth})")
    depth = decoded.depth
    trees = (scan, decoded)
    live = [_live(t, depth) for t in trees]
    key = np.zeros(1, np.uint64)
    sides = [_node_side(t.levels[0], np.zeros(1, np.int64), live[i][0], last=depth == 0)
             for i, t in enumerate(trees)]
    leaves = []
    for d in range(depth + 1):
        s, o = sides
        emit_scan = ((s.kind == LEAF) & (o.kind != SPLIT)) if d < depth else s.kind == LEAF
        emit_out = (o.kind == LEAF) & (s.kind == EMPTY)
        leaves.append([_leaf_rows(trees[i], d, key[m], side.take(m))
                       for i, (side, m) in enumerate(((s, emit_scan), (o, emit_out))) if m.any()])
        if d == depth:
            break
        go = (o.kind == SPLIT) | (s.kind == SPLIT)
        key = morton.child_keys(key[go])
        sides = [_children(trees[i], d, side.take(go), key, live[i][d + 1], last=d + 1 == depth,
                           tolerance=scan.threshold if i == 0 else None) for i, side in enumerate(sides)]
    out = {}
    for d, per in enumerate(leaves):
        for keys, planes, errors, counts in (p for p in per):
            for k, p, e, c in zip(keys, planes, errors, counts):
                out[(d, int(k))] = (p.tobytes(), e.tobytes(), int(c))
    return out


def _centres(keys: np.ndarray, size: float) -> np.ndarray:
    """Centres (N, 3) of the octants ``keys`` of edge ``size`` (``OctreeLevel.centers`` for a subset)."""
    return (morton.decode(keys)[0] + 0.5) * size


def _node_side(level: OctreeLevel, rows: np.ndarray, live: np.ndarray, last: bool) -> _Side:
    """The state of a tree's own nodes ``rows`` of ``level`` (``live``: per node of the level,
    whether it holds a patch; at the output's last depth every non-empty node is a leaf)."""
    kind = level.label[rows].copy()
    kind[~live[rows]] = EMPTY
    if last:
        kind[kind != EMPTY] = LEAF
    normal = np.zeros((len(rows), 3))
    plane_level = np.zeros(len(rows))
    leaf = kind == LEAF                                   # only a leaf's plane is passed on
    if leaf.any():
        at = rows[leaf]
        n = level.plane[at, :3].astype(np.float64)
        normal[leaf] = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        plane_level[leaf] = (normal[leaf] * level.centers(at)).sum(1) - level.plane_offsets(at)
    source = np.stack([np.full(len(rows), level.depth), rows], 1)
    return _Side(kind, rows.astype(np.int64), normal, plane_level, source)


def _children(tree: Octree, depth: int, side: _Side, child_key: np.ndarray, live: np.ndarray,
              last: bool, tolerance: float | None) -> _Side:
    """The states of the eight children (``child_key``, 8 per octant in order) of ``side``'s
    octants at ``depth``: a split node's children are its nodes (``live``: :func:`_live`'s at the
    children's depth; all non-empty ones are leaves when ``last``); a leaf's (or claimed) plane
    passes to the children it crosses as a leaf, to those within ``tolerance`` of it (None: none)
    as claimed."""
    n = len(side.kind)
    up = np.repeat(np.arange(n), 8)
    lv = tree.levels[depth]
    kind_up = np.repeat(side.kind, 8)
    nodes = kind_up == SPLIT
    rows = np.full(8 * n, -1, np.int64)
    slot = np.arange(8 * n) & 7
    rows[nodes] = lv.child[side.row[up[nodes]]].astype(np.int64) * 8 + slot[nodes]
    out = _Side(np.full(8 * n, EMPTY, np.int8), np.full(8 * n, -1, np.int64), side.normal[up],
                np.repeat(side.level, 8), side.source[up])
    if nodes.any():
        own = _node_side(tree.levels[depth + 1], rows[nodes], live, last=last)
        for field in ("kind", "row", "normal", "level", "source"):
            getattr(out, field)[nodes] = getattr(own, field)
    planes = (kind_up == LEAF) | (kind_up == _CLAIMED)
    if planes.any():
        size = 1.0 / (1 << (depth + 1))
        centre = _centres(child_key[planes], size)
        gap = np.abs((out.normal[planes] * centre).sum(1) - out.level[planes])
        reach = 0.5 * size * np.abs(out.normal[planes]).sum(1)
        kind = np.where(gap <= reach, LEAF, EMPTY).astype(np.int8)
        if tolerance is not None:
            kind[(kind == EMPTY) & (gap <= reach + tolerance)] = _CLAIMED
        kind[(kind == LEAF) & (kind_up[planes] == _CLAIMED)] = _CLAIMED
        out.kind[planes] = kind
    return out


def _leaf_rows(tree: Octree, depth: int, key: np.ndarray, side: _Side):
    """(keys, planes, errors, point counts) of leaves at ``depth`` from ``side``: a node's own
    row as it is; a plane refined from a coarser leaf re-expressed for its octant, with the
    error of the leaf it came from and no point count (not known per child)."""
    lv = tree.levels[depth]
    own = side.row >= 0
    plane = np.zeros((len(key), 4), np.float32)
    error = np.full(len(key), np.nan, np.float32)
    npoints = np.zeros(len(key), np.int32)
    rows = side.row[own]
    plane[own], error[own], npoints[own] = lv.plane[rows], lv.error[rows], lv.npoints[rows]
    inherited = np.flatnonzero(~own)
    if len(inherited):
        size = lv.size
        centre = _centres(key[inherited], size)
        normal = side.normal[inherited]
        offset = (normal * centre).sum(1) - side.level[inherited]
        plane[inherited, :3] = normal
        plane[inherited, 3] = offset / (PLANE_SCALE * size)
        for d in np.unique(side.source[inherited, 0]):
            at = inherited[side.source[inherited, 0] == d]
            error[at] = tree.levels[d].error[side.source[at, 1]]
    return key, plane, error, npoints


def reference_tree(like: Octree, leaves) -> Octree:
    """The octree whose leaves are, per depth, the given (keys, planes, errors, point counts) or
    None (the keys of all depths cover disjoint regions): every ancestor of a leaf split (with all
    8 children), everything else empty: the NumPy formulation, level by level, kept to check the
    compiled construction (``model.octree.fuse._fill_level``) array for array."""
    depth = like.depth
    leaf_keys = [p[0] if p is not None else np.zeros(0, np.uint64) for p in leaves]
    # the ancestors of the leaves, per depth, bottom up: the parents of the next depth's leaves and splits
    split_keys = [np.zeros(0, np.uint64)] * (depth + 1)
    for d in range(depth - 1, -1, -1):
        split_keys[d] = np.unique(morton.parent_keys(np.concatenate([leaf_keys[d + 1], split_keys[d + 1]])))
    levels: list[OctreeLevel] = []
    key = np.zeros(1, np.uint64)
    parent = np.full(1, -1, np.int32)
    for d in range(depth + 1):
        n = len(key)
        label = np.full(n, EMPTY, np.int8)
        plane = np.zeros((n, 4), np.float32)
        error = np.full(n, np.nan, np.float32)
        npoints = np.zeros(n, np.int32)
        if leaves[d] is not None:
            keys, planes, errors, counts = leaves[d]
            at = morton.lookup(key, keys)
            if np.any(at == n):
                raise ValueError(f"depth {d}: leaves nest or lie outside the tree")
            label[at] = LEAF
            plane[at], error[at], npoints[at] = planes, errors, counts
        split = (morton.lookup(split_keys[d], key) < len(split_keys[d])) | (d < like.full_depth)
        if d == depth:
            split[:] = False
        if np.any(split & (label == LEAF)):
            raise ValueError(f"depth {d}: a leaf contains another leaf")
        label[split] = SPLIT
        split_idx = np.flatnonzero(split)
        child = np.full(n, -1, np.int32)
        child[split_idx] = np.arange(len(split_idx), dtype=np.int32)
        levels.append(OctreeLevel(depth=d, key=key, label=label, child=child, parent=parent, plane=plane,
                                  error=error, npoints=npoints))
        key = morton.child_keys(key[split_idx])
        parent = np.repeat(split_idx.astype(np.int32), 8)
    return Octree(depth=depth, levels=levels, adaptive=True, threshold=like.threshold,
                  full_depth=like.full_depth, adaptive_depth=like.adaptive_depth,
                  normalizations=list(like.normalizations))
