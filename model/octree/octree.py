"""The octree data structure: one :class:`OctreeLevel` of flat arrays per depth.

Nodes of a depth are sorted by key (batch index first).  A split node is the k-th split node of
its depth; its 8 children are nodes ``8k .. 8k+7`` of the next depth, in slot order
``4x + 2y + z``.  Coordinates inside the octree are those of the unit cube ``[0, 1]^3``;
:class:`Normalization` maps them back to the input's coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from . import keys as morton

EMPTY, SPLIT, LEAF = 0, 1, 2
"""Node labels: empty octant, octant with 8 children, leaf octant carrying a patch."""
PLANE_SCALE = np.sqrt(3.0) / 2.0
"""d* is stored in units of sqrt(3)/2 * h_l, so |d*| <= 1 whenever the plane cuts the octant."""


@dataclass(frozen=True)
class Normalization:
    """Maps unit-cube coordinates back to the input's: ``world = (cube - 0.5) * scale + center``."""

    center: np.ndarray
    scale: float

    def to_world(self, cube: np.ndarray) -> np.ndarray:
        world = np.array(cube, dtype=np.float64)        # a copy, worked on in place: one array, not three
        world -= 0.5
        world *= self.scale
        world += self.center
        return world

    def to_cube(self, world: np.ndarray) -> np.ndarray:
        return (np.asarray(world, dtype=np.float64) - self.center) / self.scale + 0.5


@dataclass
class OctreeLevel:
    """All nodes of one depth, as flat arrays of equal length N."""

    depth: int
    key: np.ndarray        # (N,) uint64 Morton key with the batch index in bits 48..63
    label: np.ndarray      # (N,) int8: EMPTY, SPLIT or LEAF (non-empty nodes at max depth are LEAF)
    child: np.ndarray      # (N,) int32: k for the k-th split node (children 8k..8k+7), else -1
    parent: np.ndarray     # (N,) int32: index of the parent node at depth-1 (-1 at depth 0)
    plane: np.ndarray      # (N, 4) float32 (nx, ny, nz, d*), zeros for empty nodes
    error: np.ndarray      # (N,) float32 patch error in cube units; NaN where not measured
    npoints: np.ndarray    # (N,) int32 number of input points inside the octant
    neighbors: np.ndarray | None = None  # (N, 27) int32 3x3x3 neighbours (index or -1)

    def __len__(self) -> int:
        return len(self.key)

    @property
    def size(self) -> float:
        """Edge length h_l of an octant of this depth, in cube units."""
        return 1.0 / (1 << self.depth)

    @property
    def nonempty(self) -> np.ndarray:
        return self.label != EMPTY

    def split_nodes(self) -> np.ndarray:
        """Indices of the split nodes, ascending; the k-th owns children 8k..8k+7 (checked)."""
        split = np.flatnonzero(self.child >= 0)
        if not np.array_equal(self.child[split], np.arange(len(split))):
            raise ValueError(f"depth {self.depth}: split nodes are not numbered in index order")
        return split

    @property
    def batch(self) -> np.ndarray:
        return morton.batch_of(self.key)

    def coords(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Integer octant coordinates (N, 3) at this depth (of the nodes ``rows`` only, if given)."""
        return morton.decode(self.key if rows is None else self.key[rows])[0]

    def centers(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Octant centres (N, 3) in cube units (of the nodes ``rows`` only, if given)."""
        return (self.coords(rows) + 0.5) * self.size

    def plane_offsets(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Plane offsets relative to the octant centre in cube units: ``n . (x - c) + d = 0`` (of
        the nodes ``rows`` only, if given)."""
        d = self.plane[:, 3] if rows is None else self.plane[rows, 3]
        return d.astype(np.float64) * PLANE_SCALE * self.size


@dataclass
class Octree:
    """A (batch of) patch-guided adaptive or full octree(s), depths 0..depth."""

    depth: int
    levels: list[OctreeLevel]
    adaptive: bool
    threshold: float                 # split threshold in cube units (delta hat)
    full_depth: int = 2
    adaptive_depth: int = 4
    normalizations: list[Normalization] = field(default_factory=list)  # one per shape

    @property
    def batch_size(self) -> int:
        return len(self.normalizations)

    def nodes_per_depth(self) -> list[int]:
        return [len(lv) for lv in self.levels]

    def nonempty_per_depth(self) -> list[int]:
        return [int(lv.nonempty.sum()) for lv in self.levels]

    def leaves_per_depth(self) -> list[int]:
        return [int((lv.label == LEAF).sum()) for lv in self.levels]

    @property
    def has_neighbors(self) -> bool:
        return all(lv.neighbors is not None for lv in self.levels)
