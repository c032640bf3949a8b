"""A decoded octree's leaves on the grid of its finest cells: which leaf owns each cell, and the
leaf planes' values at the corners of the cells near them.

The grid covers the leaves' bounding box with at least :data:`PAD` cells of padding on every
side, so that its outermost corners, and the cells they belong to, are outside the shape; its
bounds are multiples of ``align`` cells, so that blocks of that many cells sit where octree
cubes do.  Array cell ``i`` along an axis is the finest cell ``origin + i`` (cell ``c`` spans
``[c h, (c + 1) h]``, ``h = 2^-D``); corner ``i`` is at ``(origin + i) h``.  Arrays are dense over
the box; the work per leaf is in proportion to
the cells of its cube.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..octree import LEAF, Octree
from ..octree.geometry import bounding_box
from ..octree.jit import compiled

PAD = 2
CORNER_OFFSETS = np.array([[c & 1, c >> 1 & 1, c >> 2 & 1] for c in range(8)])


@dataclass
class Leaves:
    """The leaves of one shape: integer cube origin in finest cells, edge in cells, unit normal
    and the plane's constant: the plane is ``normal . x + const = 0`` in cube coordinates."""

    origin: np.ndarray     # (L, 3) int64
    cells: np.ndarray      # (L,) int64 edge length in finest cells
    normal: np.ndarray     # (L, 3) float64
    const: np.ndarray      # (L,) float64

    def __len__(self) -> int:
        return len(self.cells)

    def values(self, index: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Signed distances of ``points`` (M, 3) to the planes of leaves ``index`` (M,)."""
        return np.einsum("ij,ij->i", points, self.normal[index]) + self.const[index]


def leaves_of(octree: Octree) -> Leaves:
    """Every leaf of a single-shape octree (planes read as :func:`model.octree.patches.leaf_patches` does)."""
    parts = []
    for lv in octree.levels:
        sel = np.flatnonzero(lv.label == LEAF)
        if not len(sel):
            continue
        f = 1 << (octree.depth - lv.depth)
        n = lv.plane[sel, :3].astype(np.float64)
        n /= np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
        const = lv.plane_offsets(sel) - np.einsum("ij,ij->i", n, lv.centers(sel))
        parts.append((lv.coords(sel).astype(np.int64) * f, np.full(len(sel), f, np.int64), n, const))
    if not parts:
        return Leaves(np.zeros((0, 3), np.int64), np.zeros(0, np.int64), np.zeros((0, 3)), np.zeros(0))
    return Leaves(*[np.concatenate(c) for c in zip(*parts)])


@dataclass
class Grid:
    """The finest grid over one shape's leaves: ``n`` cells per unit length, the finest cell
    ``origin`` of array cell 0, the owning leaf of every cell (-1: none), and at corners near a
    plane the planes' mean value (negative inside) and the nearest plane's leaf.

    Invariant: ``near`` holds every corner of a cell whose owner's plane passes within ``band``
    cell diagonals of the cell's centre (a *band* cell); ``value`` there is the mean of the planes'
    values over the band cells around the corner (each cell counts once, so a large leaf owning
    several of them counts more), and ``leaf`` is the leaf whose plane is nearest the corner
    among them."""

    n: int
    origin: np.ndarray       # (3,) int64
    owner: np.ndarray        # cells: int32 leaf or -1
    near: np.ndarray         # corners: bool
    value: np.ndarray        # corners: float32 (inf where not near)
    leaf: np.ndarray         # corners: int32 (-1 where not near)

    @property
    def h(self) -> float:
        return 1.0 / self.n

    def corner_positions(self, index: np.ndarray) -> np.ndarray:
        """Cube coordinates of corners given as (M, 3) array indices."""
        return (index + self.origin) * self.h


def rasterise(leaves: Leaves, align: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """(origin, owner): the finest cell of array cell 0 and the leaf owning every cell (-1: none)
    over the leaves' bounding box, padded and aligned as :class:`Grid` says."""
    origin = (bounding_box(leaves.origin)[0] - PAD) // align * align
    size = -(-(bounding_box(leaves.origin + leaves.cells[:, None])[1] + PAD - origin) // align) * align
    owner = np.full(tuple(size), -1, np.int32)
    strides = np.array([size[1] * size[2], size[2], 1])
    flat = owner.ravel()
    for f in np.unique(leaves.cells):
        sel = np.flatnonzero(leaves.cells == f)
        sub = np.stack(np.meshgrid(*[np.arange(f)] * 3, indexing="ij"), -1).reshape(-1, 3)
        flat[((leaves.origin[sel, None, :] - origin + sub[None]).reshape(-1, 3)) @ strides] = np.repeat(sel, len(sub))
    return origin, owner


def build_grid(leaves: Leaves, depth: int, band: float = 1.0, align: int = 1,
               raster: tuple[np.ndarray, np.ndarray] | None = None) -> Grid:
    """Rasterise ``leaves`` onto the finest grid of ``depth`` over their bounding box (bounds
    multiples of ``align`` cells; ``raster``: :func:`rasterise`'s result when already made); a
    cell is near its owner's plane when the plane passes within ``band`` cell diagonals of its
    centre."""
    n = 1 << depth
    h = 1.0 / n
    origin, owner = raster if raster is not None else rasterise(leaves, align)
    size = np.array(owner.shape)
    shape = tuple(size + 1)
    total = np.zeros(int(np.prod(shape)), np.float32)             # flat over the corners
    votes = np.zeros(total.size, np.uint8)
    nearest = np.full(total.size, np.inf, np.float32)
    leaf_at = np.full(total.size, -1, np.int32)
    reach = band * np.sqrt(3.0) * h
    strides = np.array([shape[1] * shape[2], shape[2], 1])
    corner_step = CORNER_OFFSETS @ strides                        # flat offset of each cell corner
    for f in np.unique(leaves.cells):
        sel = np.flatnonzero(leaves.cells == f)
        sub = np.stack(np.meshgrid(*[np.arange(f)] * 3, indexing="ij"), -1).reshape(-1, 3)      # (f^3, 3)
        index = (leaves.origin[sel, None, :] - origin + sub[None]).reshape(-1, 3)                 # array cells
        ids = np.repeat(sel, len(sub))
        normal = leaves.normal[ids]
        centre = np.einsum("ij,ij->i", (index + origin + 0.5) * h, normal) + leaves.const[ids]   # plane at the centre
        close = np.abs(centre) <= reach
        index, ids, normal, centre = index[close], ids[close], normal[close], centre[close]
        base = index @ strides
        values = np.stack([(centre + (normal @ off) * h).astype(np.float32) for off in CORNER_OFFSETS - 0.5])
        _vote(base, corner_step, values, ids.astype(np.int32), total, votes, nearest, leaf_at)
    near = votes > 0
    value = np.where(near, total / np.maximum(votes, 1), np.inf).astype(np.float32)
    near, value, leaf_at = near.reshape(shape), value.reshape(shape), leaf_at.reshape(shape)
    return Grid(n, origin, owner, near, value, leaf_at)


@compiled
def _vote(base: np.ndarray, corner_step: np.ndarray, values: np.ndarray, ids: np.ndarray, total: np.ndarray,
          votes: np.ndarray, nearest: np.ndarray, leaf_at: np.ndarray) -> None:
    """Each cell's plane values ``values`` (8, M) at its corners (flat ``base + corner_step``) added to
    ``total`` and counted in ``votes``; ``nearest`` and ``leaf_at`` keep the least magnitude and
    its leaf (the first on a tie), corner offset by corner offset as the cells come."""
    for k in range(len(corner_step)):
        for i in range(len(base)):
            at = base[i] + corner_step[k]
            v = values[k, i]
            total[at] += v
            votes[at] += 1
            if abs(v) < nearest[at]:
                nearest[at] = abs(v)
                leaf_at[at] = ids[i]
