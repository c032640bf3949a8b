"""Batching: several octrees of the same depth merged into one, shape-major, indices offset."""

from __future__ import annotations

import dataclasses

import numpy as np

from . import keys as morton
from .neighbors import build_neighbors
from .octree import SPLIT, Octree, OctreeLevel

_MORTON_MASK = np.uint64((1 << morton.BATCH_SHIFT) - 1)


def merge_octrees(octrees: list[Octree], neighbors: bool = False) -> Octree:
    """One octree holding ``octrees`` as batch items 0..B-1 (in the given order).

    Keys get the batch index in their high bits; parent, child and neighbour indices are offset
    so that every table equals the per-shape table plus the node count of earlier shapes.
    Neighbour tables are merged when every input has them; otherwise ``neighbors`` builds the
    merged octree's tables (once for the batch, not per shape).  A single octree is its own batch:
    its levels' arrays are shared, not copied (a request's scan: offsetting them by zero cost 6 ms).
    """
    if not octrees:
        raise ValueError("merge_octrees needs at least one octree")
    first = octrees[0]
    if len(octrees) == 1:
        merged = dataclasses.replace(first, levels=[dataclasses.replace(lv) for lv in first.levels],
                                     normalizations=list(first.normalizations))
        if neighbors and not merged.has_neighbors:
            build_neighbors(merged)
        return merged
    for o in octrees[1:]:
        if (o.depth, o.full_depth, o.adaptive_depth) != (first.depth, first.full_depth, first.adaptive_depth):
            raise ValueError("octrees to merge must share depth, full_depth and adaptive_depth")
    with_neigh = all(o.has_neighbors for o in octrees)
    levels = []
    batch_base = 0
    bases = []
    for o in octrees:
        bases.append(batch_base)
        batch_base += o.batch_size
    for d in range(first.depth + 1):
        parts = [o.levels[d] for o in octrees]
        n_off = np.cumsum([0] + [len(p) for p in parts])[:-1]
        c_off = np.cumsum([0] + [int((p.child >= 0).sum()) for p in parts])[:-1]
        p_off = (np.cumsum([0] + [len(o.levels[d - 1]) for o in octrees])[:-1]
                 if d > 0 else np.zeros(len(parts), dtype=np.int64))
        key = np.concatenate([
            (p.key & _MORTON_MASK) | ((morton.batch_of(p.key) + b).astype(np.uint64) << np.uint64(morton.BATCH_SHIFT))
            for p, b in zip(parts, bases)])
        child = np.concatenate([np.where(p.child >= 0, p.child + c, -1) for p, c in zip(parts, c_off)])
        parent = np.concatenate([np.where(p.parent >= 0, p.parent + q, -1) for p, q in zip(parts, p_off)])
        neigh = (np.concatenate([np.where(p.neighbors >= 0, p.neighbors + n, -1) for p, n in zip(parts, n_off)])
                 if with_neigh else None)
        levels.append(OctreeLevel(
            depth=d, key=key, label=np.concatenate([p.label for p in parts]),
            child=child.astype(np.int32), parent=parent.astype(np.int32),
            plane=np.concatenate([p.plane for p in parts]),
            error=np.concatenate([p.error for p in parts]),
            npoints=np.concatenate([p.npoints for p in parts]),
            neighbors=None if neigh is None else neigh.astype(np.int32)))
    merged = Octree(depth=first.depth, levels=levels, adaptive=all(o.adaptive for o in octrees),
                    threshold=first.threshold, full_depth=first.full_depth,
                    adaptive_depth=first.adaptive_depth,
                    normalizations=[n for o in octrees for n in o.normalizations])
    if neighbors and not with_neigh:
        build_neighbors(merged)
    return merged


def split_octree(octree: Octree, neighbors: bool = True) -> list[Octree]:
    """The inverse of :func:`merge_octrees`: one octree per batch item (keys without batch bits).

    Nodes are shape-major at every depth, so each shape is a slice; child and parent indices are
    renumbered, and neighbour tables rebuilt when the batch had them (unless ``neighbors`` is
    False: meshing and sampling need none).
    """

    out = []
    bounds = [np.searchsorted(lv.key >> np.uint64(morton.BATCH_SHIFT),
                              np.arange(octree.batch_size + 1, dtype=np.uint64)) for lv in octree.levels]
    for b in range(octree.batch_size):
        levels, parent = [], np.full(1, -1, dtype=np.int32)
        for lv, bd in zip(octree.levels, bounds):
            sl = slice(int(bd[b]), int(bd[b + 1]))
            label = lv.label[sl]
            split = np.flatnonzero(label == SPLIT)
            child = np.full(len(label), -1, dtype=np.int32)
            child[split] = np.arange(len(split), dtype=np.int32)
            levels.append(OctreeLevel(depth=lv.depth, key=lv.key[sl] & _MORTON_MASK, label=label,
                                      child=child, parent=parent[:len(label)], plane=lv.plane[sl],
                                      error=lv.error[sl], npoints=lv.npoints[sl]))
            parent = np.repeat(split.astype(np.int32), 8)
        single = Octree(depth=octree.depth, levels=levels, adaptive=octree.adaptive,
                        threshold=octree.threshold, full_depth=octree.full_depth,
                        adaptive_depth=octree.adaptive_depth, normalizations=[octree.normalizations[b]])
        if neighbors and octree.has_neighbors:
            build_neighbors(single)
        out.append(single)
    return out
