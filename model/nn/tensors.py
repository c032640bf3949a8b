"""Torch views of a NumPy :class:`~model.octree.Octree`: the per-depth tables the network ops read.

Converted once per batch (:meth:`OctreeTensors.from_octree`); the ops in :mod:`model.nn.ops` take
these tensors as plain arguments, so the networks never touch NumPy inside ``forward``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from ..octree import EMPTY, Octree, OctreeLevel


@dataclass
class LevelTensors:
    """The N octants of one depth: neighbour, parent and split tables, labels and plane signal."""

    neighbors: torch.Tensor   # (N, 27) int64, column (dx+1)*9 + (dy+1)*3 + (dz+1), -1 if missing
    split: torch.Tensor       # (K,) int64 ascending indices of the split nodes; the k-th one owns
                              # nodes 8k .. 8k+7 of the next depth (slot 4x + 2y + z)
    parent: torch.Tensor      # (N,) int64 index of the parent at depth-1 (-1 at depth 0)
    label: torch.Tensor       # (N,) int64: EMPTY 0, SPLIT 1, LEAF 2
    plane: torch.Tensor       # (N, 4) float32 (nx, ny, nz, d*), zeros for empty octants
    nonempty: torch.Tensor    # (N,) bool

    def __len__(self) -> int:
        return self.label.shape[0]

    @classmethod
    def from_level(cls, level: OctreeLevel) -> LevelTensors:
        """Copy one :class:`OctreeLevel` into torch tensors (indices widened to int64)."""
        if level.neighbors is None:
            raise ValueError(f"depth {level.depth} has no neighbour table (build with neighbors=True)")
        split = level.split_nodes()
        return cls(neighbors=torch.from_numpy(level.neighbors.astype(np.int64)),
                   split=torch.from_numpy(split.astype(np.int64)),
                   parent=torch.from_numpy(level.parent.astype(np.int64)),
                   label=torch.from_numpy(level.label.astype(np.int64)),
                   plane=torch.from_numpy(np.array(level.plane, dtype=np.float32)),
                   nonempty=torch.from_numpy(level.label != EMPTY))

    def to(self, device: torch.device | str) -> LevelTensors:
        return LevelTensors(**{name: getattr(self, name).to(device) for name in self.__dataclass_fields__})


@dataclass
class OctreeTensors:
    """Every depth 0..depth of a (batched) octree as :class:`LevelTensors`."""

    depth: int
    batch_size: int
    levels: list[LevelTensors]

    @classmethod
    def from_octree(cls, octree: Octree) -> OctreeTensors:
        """Convert once per batch; the octree must carry neighbour tables."""
        return cls(depth=octree.depth, batch_size=octree.batch_size,
                   levels=[LevelTensors.from_level(lv) for lv in octree.levels])

    def to(self, device: torch.device | str) -> OctreeTensors:
        return OctreeTensors(self.depth, self.batch_size, [lv.to(device) for lv in self.levels])
