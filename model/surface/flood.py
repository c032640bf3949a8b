"""Compiled walks over the finest grid's corners (numba): the floods that decide inside and outside
(:mod:`.sign`) and the repair of the cells' configurations (:mod:`.dmc`).

Each is the SciPy formulation it replaced, walked once instead of pass after pass over the whole
grid: :func:`reached` is ``ndimage.label`` (6-connected) keeping the parts that touch the grid's
border; :func:`eroded` is ``ndimage.binary_erosion`` with the 6-neighbour cross iterated
``steps`` times (``border_value=1``), a breadth-first walk from the corners not in the mask;
:func:`dilated` is ``ndimage.binary_dilation`` with the cross iterated ``steps`` times within a
``mask``; :func:`repaired` is the round-by-round repair, each round re-judging only the cells
around the corners the last round turned.  Arrays are C-ordered 3-D booleans; the results are
the same arrays, bit for bit (tests compare them with SciPy's on random grids).
"""

from __future__ import annotations

import numpy as np

from ..octree.jit import compiled


def reached(free: np.ndarray) -> np.ndarray:
    """The ``free`` corners joined to the grid's border through free corners (6-connected)."""
    return _reached(np.ascontiguousarray(free)).reshape(free.shape)


def fill_cavities(inside: np.ndarray) -> np.ndarray:
    """``inside`` with every outside region that does not reach the grid's border turned inside."""
    return ~reached(~inside)


def eroded(mask: np.ndarray, steps: int) -> np.ndarray:
    """``mask`` eroded ``steps`` times by the 6-neighbour cross, beyond the border counting as in
    the mask: the corners whose every corner within ``steps`` grid steps (city-block) is in it."""
    if steps <= 0:
        return mask.copy()
    return _eroded(np.ascontiguousarray(mask), steps).reshape(mask.shape)


def dilated(seed: np.ndarray, mask: np.ndarray, steps: int) -> np.ndarray:
    """``seed`` grown ``steps`` times by the 6-neighbour cross, each time only into ``mask``: the
    corners of ``mask`` reached from ``seed`` in at most ``steps`` steps through ``mask`` (and the
    seed itself)."""
    if steps <= 0:
        return seed.copy()
    return _dilated(np.ascontiguousarray(seed), np.ascontiguousarray(mask), steps).reshape(seed.shape)


def configurations(inside: np.ndarray) -> np.ndarray:
    """The 8-bit configuration of every cell (bit c set when corner c is inside)."""
    return _configurations(np.ascontiguousarray(inside))


def repaired(inside: np.ndarray, repair: np.ndarray, max_rounds: int) -> tuple[np.ndarray, int, int]:
    """Rounds of repair on a copy of ``inside``: every cell whose configuration ``repair`` (the
    table: the corner to turn inside, or -1) asks for a repair has that corner turned inside,
    unless it lies on the grid's border, all at once from the round's start; then the next round.
    When no cell asks any more, enclosed outside regions are filled (:func:`fill_cavities`), and if that
    turned corners the rounds go on.  Returns the corners, the distinct corners the rounds turned
    (filling not counted) and the rounds run (``max_rounds`` when they ran out)."""
    out = np.ascontiguousarray(inside).copy()
    nx, ny, nz = out.shape
    cells = np.arange((nx - 1) * (ny - 1) * (nz - 1), dtype=np.int64)    # round 0: every cell
    mark = np.full(out.size, -1, np.int64)
    turned = 0
    for r in range(max_rounds):
        cells, count = _repair_round(out, repair, cells, mark, r)
        turned += count
        if count:
            continue
        filled = fill_cavities(out)
        changed = np.flatnonzero((filled != out).ravel())
        if not len(changed):
            return out, turned, r
        out = filled
        cells = _cells_around(changed, out.shape)
    return out, turned, max_rounds


@compiled
def _reached(free: np.ndarray) -> np.ndarray:
    nx, ny, nz = free.shape
    flat = free.ravel()
    seen = np.zeros(flat.size, np.bool_)
    queue = np.empty(flat.size, np.int64)
    tail = 0
    for x in range(nx):                           # the border's free corners start the walk
        for y in range(ny):
            for z in range(nz):
                if x == 0 or y == 0 or z == 0 or x == nx - 1 or y == ny - 1 or z == nz - 1:
                    i = (x * ny + y) * nz + z
                    if flat[i]:
                        seen[i] = True
                        queue[tail] = i
                        tail += 1
    _walk(flat, seen, queue, 0, tail, nx, ny, nz, -1)
    return seen


@compiled
def _walk(allowed, seen, queue, head, tail, nx, ny, nz, steps) -> int:
    """Breadth first from ``queue[head:tail]`` into ``allowed`` corners not ``seen`` yet (marking
    them), ``steps`` layers at most (-1: no limit); returns the new tail."""
    syz = ny * nz
    size, stride = (nx, ny, nz), (syz, nz, 1)
    layer_end = tail
    depth = 0
    while head < tail:
        if head == layer_end:
            depth += 1
            layer_end = tail
        if steps >= 0 and depth >= steps:
            break
        i = queue[head]
        head += 1
        x, rest = divmod(i, syz)
        at = (x, rest // nz, rest % nz)
        for a in range(3):                        # the 6 neighbours inside the grid
            for step in (-1, 1):
                if not 0 <= at[a] + step < size[a]:
                    continue
                j = i + step * stride[a]
                if allowed[j] and not seen[j]:
                    seen[j] = True
                    queue[tail] = j
                    tail += 1
    return tail


@compiled
def _eroded(mask: np.ndarray, steps: int) -> np.ndarray:
    flat = mask.ravel()
    nx, ny, nz = mask.shape
    hit = ~flat                                   # within reach of a corner outside the mask
    starts = np.flatnonzero(hit)
    queue = np.empty(flat.size, np.int64)
    queue[:len(starts)] = starts
    _walk(np.ones(flat.size, np.bool_), hit, queue, 0, len(starts), nx, ny, nz, steps)
    return ~hit


@compiled
def _dilated(seed: np.ndarray, mask: np.ndarray, steps: int) -> np.ndarray:
    flat = seed.ravel()
    nx, ny, nz = seed.shape
    seen = flat.copy()
    starts = np.flatnonzero(flat)
    queue = np.empty(flat.size, np.int64)
    queue[:len(starts)] = starts
    _walk(mask.ravel(), seen, queue, 0, len(starts), nx, ny, nz, steps)
    return seen


@compiled
def _configurations(inside: np.ndarray) -> np.ndarray:
    nx, ny, nz = inside.shape
    config = np.zeros((nx - 1, ny - 1, nz - 1), np.uint8)
    for x in range(nx - 1):
        for y in range(ny - 1):
            for z in range(nz - 1):
                c = 0
                for k in range(8):
                    if inside[x + (k & 1), y + (k >> 1 & 1), z + (k >> 2 & 1)]:
                        c |= 1 << k
                config[x, y, z] = c
    return config


@compiled
def _repair_round(inside, repair, cells, mark, round_id):
    """One round over ``cells`` (flat cell indices): the corners to turn, turned; returns the cells
    around them (the next round's) and how many distinct corners were turned."""
    nx, ny, nz = inside.shape
    cy, cz = ny - 1, nz - 1
    flat = inside.ravel()
    found = np.empty(len(cells), np.int64)
    n = 0
    for c in cells:
        x, rest = divmod(c, cy * cz)
        y, z = divmod(rest, cz)
        config = 0
        for k in range(8):
            if flat[((x + (k & 1)) * ny + y + (k >> 1 & 1)) * nz + z + (k >> 2 & 1)]:
                config |= 1 << k
        fix = repair[config]
        if fix < 0:
            continue
        px, py, pz = x + (fix & 1), y + (fix >> 1 & 1), z + (fix >> 2 & 1)
        if px == 0 or py == 0 or pz == 0 or px == nx - 1 or py == ny - 1 or pz == nz - 1:
            continue                              # the grid's border stays outside
        i = (px * ny + py) * nz + pz
        if mark[i] != round_id:
            mark[i] = round_id
            found[n] = i
            n += 1
    corners = found[:n]
    for i in corners:
        flat[i] = True
    return _cells_around(corners, inside.shape), n


@compiled
def _cells_around(corners: np.ndarray, shape) -> np.ndarray:
    """The distinct cells (flat indices, ascending) with one of ``corners`` (flat) as a corner."""
    nx, ny, nz = shape
    cy, cz = ny - 1, nz - 1
    hit = np.zeros((nx - 1) * cy * cz, np.bool_)
    for i in corners:
        x, rest = divmod(i, ny * nz)
        y, z = divmod(rest, nz)
        for k in range(8):
            a, b, c = x - (k & 1), y - (k >> 1 & 1), z - (k >> 2 & 1)
            if 0 <= a < nx - 1 and 0 <= b < cy and 0 <= c < cz:
                hit[(a * cy + b) * cz + c] = True
    return np.flatnonzero(hit).astype(np.int64)

