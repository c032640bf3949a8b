"""A completed shape fused with the scan it came from: what the scan saw keeps the scan's patches.

A completion network fills what a scan misses, but re-draws what the scan saw at its own
resolution and with its own errors.  :func:`keep_scan` takes the patches of the scan's adaptive
octree wherever the scan has points and the network's patches only in the octants the scan left
empty, and returns one octree of both, so the patches, the closed surface and every mesh format
work on it unchanged.
"""

from __future__ import annotations

import numpy as np

from . import keys as morton
from .neighbors import build_neighbors
from .octree import EMPTY, LEAF, SPLIT, Octree, OctreeLevel


def keep_scan(decoded: Octree, scan: Octree, neighbors: bool = False) -> Octree:
    """The octree of ``decoded``'s leaves outside the scan's octants and ``scan``'s leaves.

    Both are single-shape octrees in the same cube (the scan's frame: a completion model decodes
    there), with keys without batch bits.  ``scan`` may be deeper than ``decoded``: its non-empty
    octants at ``decoded.depth`` then become leaves with their fitted planes.  An octant of the
    decoded tree counts as observed when the scan has a non-empty octant at its place or a leaf
    containing it; its patch is dropped.  The result keeps ``decoded``'s depth, full and adaptive
    depths, threshold and frame (normalization); its leaves never nest (invariant of an octree).
    """
    if decoded.batch_size != 1 or scan.batch_size != 1:
        raise ValueError("keep_scan takes single-shape octrees (split batches first)")
    if scan.depth < decoded.depth:
        raise ValueError(f"the scan's octree (depth {scan.depth}) is shallower than the output ({decoded.depth})")
    depth = decoded.depth
    leaves = []                                           # per depth: (keys, source level, rows)
    scan_leaf_keys = []
    for d in range(depth + 1):
        s, o = scan.levels[d], decoded.levels[d]
        mine = np.flatnonzero(s.label != EMPTY) if d == depth else np.flatnonzero(s.label == LEAF)
        seen = s.key[s.label != EMPTY]
        out = o.key[o.label == LEAF]
        observed = np.isin(out, seen)
        for e, above in enumerate(scan_leaf_keys):      # inside a coarser scan leaf
            observed |= np.isin(morton.parent_keys(out, d - e), above)
        theirs = np.flatnonzero(o.label == LEAF)[~observed]
        leaves.append(((s, mine), (o, theirs)))
        scan_leaf_keys.append(s.key[mine])
    return _from_leaves(decoded, leaves, neighbors)


def _from_leaves(like: Octree, leaves, neighbors: bool) -> Octree:
    """The octree whose leaves are the given rows of source levels (per depth, disjoint regions):
    every ancestor of a leaf split (with all 8 children), everything else empty."""
    depth = like.depth
    leaf_keys = [np.concatenate([lv.key[rows] for lv, rows in parts]) for parts in leaves]
    split_keys = [np.unique(np.concatenate([np.zeros(0, np.uint64)] + [
        morton.parent_keys(leaf_keys[e], e - d) for e in range(d + 1, depth + 1)])) for d in range(depth + 1)]
    levels: list[OctreeLevel] = []
    key = np.zeros(1, np.uint64)
    parent = np.full(1, -1, np.int32)
    for d in range(depth + 1):
        n = len(key)
        label = np.full(n, EMPTY, np.int8)
        plane = np.zeros((n, 4), np.float32)
        error = np.full(n, np.nan, np.float32)
        npoints = np.zeros(n, np.int32)
        for lv, rows in leaves[d]:
            at = morton.lookup(key, lv.key[rows])
            if np.any(at == n):
                raise ValueError(f"depth {d}: leaves nest or lie outside the tree")
            label[at] = LEAF
            plane[at], error[at], npoints[at] = lv.plane[rows], lv.error[rows], lv.npoints[rows]
        split = np.isin(key, split_keys[d]) | (d < like.full_depth)
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
    fused = Octree(depth=depth, levels=levels, adaptive=True, threshold=like.threshold,
                   full_depth=like.full_depth, adaptive_depth=like.adaptive_depth,
                   normalizations=list(like.normalizations))
    if neighbors:
        build_neighbors(fused)
    return fused
