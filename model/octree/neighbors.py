"""3x3x3 neighbour tables of every depth, derived from the parent depth's table.

A child's 27 neighbours are children of its parent's 27 neighbours, so each depth costs two
gathers of (nodes x 27) integers; keys are never searched, and neighbours never cross shapes
because roots have no neighbours but themselves.
"""

from __future__ import annotations

import numpy as np

from .octree import Octree

CENTER = 13
"""Column of the node itself: offset (0, 0, 0) has index (dx+1)*9 + (dy+1)*3 + (dz+1)."""


def _lookup_tables() -> tuple[np.ndarray, np.ndarray]:
    """For child slot c and offset o: which parent neighbour (0..26) and which of its slots."""
    par = np.zeros((8, 27), dtype=np.int64)
    slot = np.zeros((8, 27), dtype=np.int64)
    for c in range(8):
        cxyz = np.array([(c >> 2) & 1, (c >> 1) & 1, c & 1])
        for o in range(27):
            t = cxyz + np.array([o // 9, (o // 3) % 3, o % 3]) - 1
            p = t >> 1                     # floor division by 2: -1, 0 or 1
            s = t & 1
            par[c, o] = (p[0] + 1) * 9 + (p[1] + 1) * 3 + (p[2] + 1)
            slot[c, o] = s[0] * 4 + s[1] * 2 + s[2]
    return par.ravel(), slot.ravel()


_PARENT_COL, _SLOT = _lookup_tables()


def build_neighbors(octree: Octree) -> None:
    """Fill ``neighbors`` (N, 27) int32 of every level in place; -1 marks a missing neighbour."""
    levels = octree.levels
    root = np.full((len(levels[0]), 27), -1, dtype=np.int32)
    root[:, CENTER] = np.arange(len(levels[0]), dtype=np.int32)
    levels[0].neighbors = root
    slot = _SLOT.astype(np.int32)
    for lv in range(1, len(levels)):
        up = levels[lv - 1]
        # First child of every node (8k), a large negative sentinel for nodes without children,
        # and one more sentinel at index -1 so that a missing neighbour (-1) reads it too.
        first = np.append(np.where(up.child >= 0, up.child * 8, _NONE).astype(np.int32), _NONE)
        parent_neigh = np.take(up.neighbors, np.flatnonzero(up.child >= 0), axis=0)   # (K, 27)
        base = np.take(first, parent_neigh)                                           # (K, 27)
        out = np.take(base, _PARENT_COL, axis=1)                                       # (K, 216)
        out += slot
        np.maximum(out, -1, out=out)
        levels[lv].neighbors = out.reshape(-1, 27)


_NONE = np.int32(-(1 << 30))
