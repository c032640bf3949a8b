"""Octrees as a few flat arrays (for .npz records) and back; child, parent and neighbour tables are
derived on load rather than stored, since they follow from keys and labels."""

from __future__ import annotations

import numpy as np

from .neighbors import build_neighbors
from .octree import SPLIT, Normalization, Octree, OctreeLevel


def octree_to_arrays(octree: Octree, prefix: str = "") -> dict[str, np.ndarray]:
    """Flat arrays of all depths (concatenated, with ``depth_offsets``) plus the settings."""
    lv = octree.levels
    norms = np.array([[*n.center, n.scale] for n in octree.normalizations], dtype=np.float64)
    arrays = {
        "key": np.concatenate([x.key for x in lv]),
        "label": np.concatenate([x.label for x in lv]),
        "plane": np.concatenate([x.plane for x in lv]),
        "error": np.concatenate([x.error for x in lv]),
        "npoints": np.concatenate([x.npoints for x in lv]),
        "depth_offsets": np.cumsum([0] + [len(x) for x in lv]).astype(np.int64),
        "settings": np.array([octree.depth, int(octree.adaptive), octree.full_depth,
                              octree.adaptive_depth], dtype=np.int64),
        "threshold": np.array(octree.threshold, dtype=np.float64),
        "normalizations": norms,
    }
    return {prefix + k: v for k, v in arrays.items()}


def octree_from_arrays(arrays, prefix: str = "", neighbors: bool = True) -> Octree:
    """The octree stored by :func:`octree_to_arrays` (``arrays`` may be an open ``np.load``)."""
    get = lambda k: np.asarray(arrays[prefix + k])  # noqa: E731
    off = get("depth_offsets")
    depth, adaptive, full_depth, adaptive_depth = (int(v) for v in get("settings"))
    if len(off) != depth + 2:
        raise ValueError(f"corrupt octree arrays: {len(off)} depth offsets for depth {depth}")
    key, label, plane, error, npts = (get(k) for k in ("key", "label", "plane", "error", "npoints"))
    levels = []
    parent = np.full(int(off[1] - off[0]), -1, dtype=np.int32)
    for d in range(depth + 1):
        sl = slice(int(off[d]), int(off[d + 1]))
        lab = label[sl]
        split = lab == SPLIT
        child = np.full(len(lab), -1, dtype=np.int32)
        child[split] = np.arange(int(split.sum()), dtype=np.int32)
        levels.append(OctreeLevel(depth=d, key=key[sl], label=lab, child=child, parent=parent,
                                  plane=plane[sl], error=error[sl], npoints=npts[sl]))
        parent = np.repeat(np.flatnonzero(split).astype(np.int32), 8)
        if d < depth and len(parent) != off[d + 2] - off[d + 1]:
            raise ValueError(f"corrupt octree arrays: depth {d + 1} should have {len(parent)} nodes")
    norms = [Normalization(center=r[:3].copy(), scale=float(r[3])) for r in get("normalizations")]
    octree = Octree(depth=depth, levels=levels, adaptive=bool(adaptive),
                    threshold=float(get("threshold")), full_depth=full_depth,
                    adaptive_depth=adaptive_depth, normalizations=norms)
    if neighbors:
        build_neighbors(octree)
    return octree
