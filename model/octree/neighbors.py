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


def root_neighbors(n_roots: int) -> np.ndarray:
    """Neighbour table of the roots of ``n_roots`` shapes: each is its only neighbour."""
    root = np.full((n_roots, 27), -1, dtype=np.int32)
    root[:, CENTER] = np.arange(n_roots, dtype=np.int32)
    return root


def child_neighbors(neighbors: np.ndarray, child: np.ndarray) -> np.ndarray:
    """Neighbour table (8K, 27) of the children of a depth from its table and ``child`` map.

    ``child`` (N,) holds k for the k-th split node (children 8k..8k+7) and -1 elsewhere.
    """
    # First child of every node (8k) and -1 for nodes without children, plus one more -1 at
    # index -1 so that a missing neighbour (-1) reads it too.  8k | slot = 8k + slot, and
    # -1 | slot = -1: one OR gives the child's index or -1.
    first = np.append(np.where(child >= 0, child * 8, -1).astype(np.int32), np.int32(-1))
    parent_neigh = np.take(neighbors, np.flatnonzero(child >= 0), axis=0)     # (K, 27)
    base = np.take(first, parent_neigh)                                        # (K, 27)
    out = np.take(base, _PARENT_COL, axis=1)                                    # (K, 216)
    out |= _SLOT32
    return out.reshape(-1, 27)


def build_neighbors(octree: Octree) -> None:
    """Fill ``neighbors`` (N, 27) int32 of every level in place; -1 marks a missing neighbour."""
    levels = octree.levels
    levels[0].neighbors = root_neighbors(len(levels[0]))
    for lv in range(1, len(levels)):
        levels[lv].neighbors = child_neighbors(levels[lv - 1].neighbors, levels[lv - 1].child)


_SLOT32 = _SLOT.astype(np.int32)
