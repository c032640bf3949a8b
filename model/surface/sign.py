"""Inside or outside, for every corner of the finest grid.

Near the surface the leaf planes decide: a corner within a margin of its nearest plane (the
plane of a leaf whose cells it belongs to) takes that plane's side.  The margin is ``h |n|_1``
(one cell for a plane along the grid, up to sqrt(3) cells for a diagonal one), the least for
which the corners on the inside of a plane form a face-connected layer: a part thinner than a
cell (a wing, a table top) keeps a closed inside of its own, about a cell thick, instead of
vanishing.

Away from the planes, space is outside when it is reachable from the border of the grid.  The
flood passes only through corners at least ``seal`` cells from every plane band, so a gap in the
predicted surface narrower than about ``2 seal`` cells (a leaf predicted empty, a crack between
patches, a part of a scan no view saw) does not let it into the interior; the flooded region then
grows back by ``seal`` cells.  The seal starts at 1 and widens while the flood still reaches the
inside of many planes (:data:`LEAK`): the sign of a leak, unless widening does not help
(:func:`chosen_seal`).
What the flood does not reach is inside, unless it is a narrow outside pocket such as the slot
between two close parts: a region that the flooded outside touches (through corners away from
the planes) and whose surrounding plane corners are mostly on the outside of their planes.  An
enclosed cavity, such as the space between the overlapping parts of a polygon soup, is filled:
space is outside only where it can be reached from outside the shape.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage

from .flood import dilated, eroded, fill_cavities, reached
from .grid import Grid, Leaves

SIX = ndimage.generate_binary_structure(3, 1)


LEAK = 0.2
"""The share of plane corners touching the flooded outside that are on the inside of their plane,
above which the flood is taken to have leaked into the interior (measured: at most 0.11 where it
did not, on thin and thick shapes; 0.43 where it did) and is tried again with a wider seal."""
DROP = 0.5
"""Where no seal brings the share to :data:`LEAK`, a seal that brings it to this fraction of the
first seal's is taken to have closed a leak; shares that stay above it are thin parts, not a leak
(:func:`chosen_seal`).  Measured at depth 6 on 21 real meshes: real leaks fall under LEAK (a
scan's open bottom 0.39 -> 0.002); thin-walled shapes stay flat (a chair 0.43 -> 0.43, an
airplane 0.54 -> 0.54)."""


def inside_corners(grid: Grid, leaves: Leaves, seals: tuple[int, ...] = (1, 2, 3, 4)) -> np.ndarray:
    """Boolean array over the grid's corners: True inside the shape.  ``seals``: the seal widths
    tried in turn until the flood does not leak (the last one stays)."""
    margin = np.abs(leaves.normal).sum(-1) * grid.h              # h |n|_1: a face-connected layer
    decisive = grid.near.copy()
    at = np.flatnonzero(grid.near)                                # judged where a plane is near only
    decisive.ravel()[at] = np.abs(grid.value.ravel()[at]) <= margin[np.maximum(grid.leaf.ravel()[at], 0)]
    plane_inside = decisive & (grid.value < 0)
    far = ~decisive
    floods, shares = [], []
    for seal in seals:
        floods.append(_flood(far, seal))
        touching = _touching(floods[-1]) & decisive
        shares.append((touching & plane_inside).sum() / max(touching.sum(), 1))
        if shares[-1] <= LEAK:
            break
    outside = floods[chosen_seal(shares)]
    rest = far & ~outside
    inside = plane_inside | rest
    if rest.any():
        regions, count = ndimage.label(rest, SIX)
        votes = np.zeros(count + 1)                           # plane corners around: outside - inside
        reached = np.zeros(count + 1, bool)
        for axis in range(3):
            for step in (1, -1):
                nb = np.roll(regions, step, axis)             # the region of the neighbour across
                touch = decisive & (nb > 0)
                votes += np.bincount(nb[touch], np.where(plane_inside[touch], -1.0, 1.0), minlength=count + 1)
                reached[nb[outside & (nb > 0)]] = True
        pocket = reached & (votes > 0)
        pocket[_border_labels(regions)] = True                # the grid's border is outside the leaves' box
        pocket[0] = False
        inside &= ~pocket[regions]
    return fill_cavities(inside)


def chosen_seal(shares: list[float]) -> int:
    """Which of the seals tried to use, given the share of plane corners touching each one's flood
    that are on the inside of their plane: the first at most :data:`LEAK` (a flood that did not
    leak); if none is, the first that halved the first seal's share (a leak that a wider seal
    closes), else the first.  A share that stays high whatever the seal is no leak: the backs of
    parts thinner than a cell, whose one plane has the outside on both sides; sealing wider then
    only fills the slots between such parts (measured: a chair's slats, an airplane's tail)."""
    for k, share in enumerate(shares):
        if share <= LEAK:
            return k
    for k, share in enumerate(shares):
        if share <= DROP * shares[0]:
            return k
    return 0


def _flood(far: np.ndarray, seal: int) -> np.ndarray:
    """The far corners reached from the grid's border through corners at least ``seal`` steps
    from the plane bands, grown back by ``seal`` steps within the far corners."""
    outside = reached(eroded(far, seal))
    return dilated(outside, far, seal)


def _touching(mask: np.ndarray) -> np.ndarray:
    """Corners with a face neighbour in ``mask``."""
    out = np.zeros_like(mask)
    for axis in range(3):
        for step in (1, -1):
            out |= np.roll(mask, step, axis)
    return out


def _border_labels(labels: np.ndarray) -> np.ndarray:
    found = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                      labels[:, :, [0, -1]].ravel()]))
    return found[found > 0]
