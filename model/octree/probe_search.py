"""patch->surface of the patch error, compiled (numba): for every probe on a patch, the distance to
the nearest point of its own octant, found on a grid of the patch's plane.

Invariants: the distances are those the per-depth k-d tree of :mod:`model.octree.patch_error`
reads (``cKDTree.query(k=1, distance_upper_bound=bound)``), bit for bit: the same shifted
coordinates (octant ``i`` moved by ``i * SEPARATION`` along x), the same squared distance
``dx*dx + dy*dy + dz*dz`` in that order, its square root, infinity unless the squared distance is
below ``bound * bound``.  The grid only prunes: a cell is skipped when its in-plane distance to the
probe (a lower bound of the 3D distance, less :data:`SLACK` for rounding) already exceeds the
nearest distance found, or when a point within the probe's tolerance has been found (the probe
then reads zero whichever point is nearest).
"""

from __future__ import annotations

import numpy as np

from .geometry import PatchProbes
from .jit import compiled
from .parallel import WORKERS, run_parts, split

SLACK = 1e-9
"""Cube units taken off every in-plane lower bound: far above the rounding of the shifted
coordinates (1e-11 for 10^4 octants), far below any sampling distance."""
POINTS_PER_CELL = 4.0
"""Each octant's plane grid aims at this many of its points per cell."""
PARALLEL_PROBES = 100_000
"""Below this many probes one thread answers them all (a thread pool costs more than it saves)."""


@compiled
def _bin(pu: np.ndarray, pv: np.ndarray, pstart: np.ndarray, radius: float,
         cells: np.ndarray, coff: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each octant's points sorted by cell of its ``cells[t]`` x ``cells[t]`` grid over
    [-radius, radius]^2 of its plane: the order (indices into the points) and, per octant, the
    first entry of each cell (``coff[t]`` + cell, one past the end at the last)."""
    order = np.empty(len(pu), np.int64)
    first = np.zeros(coff[-1], np.int64)
    for t in range(len(pstart) - 1):
        kc = cells[t]
        size = 2.0 * radius / kc
        base = coff[t]
        for p in range(pstart[t], pstart[t + 1]):
            cu = min(max(int((pu[p] + radius) / size), 0), kc - 1)
            cv = min(max(int((pv[p] + radius) / size), 0), kc - 1)
            first[base + cu * kc + cv + 1] += 1
        first[base] = pstart[t]
        for c in range(kc * kc):
            first[base + c + 1] += first[base + c]
        fill = first[base:base + kc * kc].copy()
        for p in range(pstart[t], pstart[t + 1]):
            cu = min(max(int((pu[p] + radius) / size), 0), kc - 1)
            cv = min(max(int((pv[p] + radius) / size), 0), kc - 1)
            c = cu * kc + cv
            order[fill[c]] = p
            fill[c] += 1
    return order, first


@compiled
def _scan_cell(c: int, x: float, y: float, z: float, mx: np.ndarray, my: np.ndarray, mz: np.ndarray,
               order: np.ndarray, first: np.ndarray, best: float, tol2: float, bound2: float) -> tuple[float, bool]:
    """The least squared distance from (x, y, z) to the points of cell ``c`` and ``best``; and
    whether one of them lies within the tolerance (and the bound): the probe then reads zero."""
    for s in range(first[c], first[c + 1]):
        p = order[s]
        dx = x - mx[p]
        dy = y - my[p]
        dz = z - mz[p]
        d2 = dx * dx + dy * dy + dz * dz
        if d2 < best:
            best = d2
            d = np.sqrt(d2)
            if d * d - tol2 <= 0.0 and d2 < bound2:
                return best, True
    return best, False


@compiled
def _nearest(t: int, x: float, y: float, z: float, qu: float, qv: float, tol: float,
             mx: np.ndarray, my: np.ndarray, mz: np.ndarray, order: np.ndarray, first: np.ndarray,
             cells: np.ndarray, coff: np.ndarray, radius: float, bound2: float) -> float:
    """sqrt(max(d^2 - tol^2, 0)) of one probe of octant ``t`` at (x, y, z) (shifted), in-plane
    (qu, qv) (module invariants): rings of cells around the probe's cell, nearest first."""
    kc = cells[t]
    size = 2.0 * radius / kc
    base = coff[t]
    cu = min(max(int((qu + radius) / size), 0), kc - 1)
    cv = min(max(int((qv + radius) / size), 0), kc - 1)
    tol2 = tol * tol
    best = np.inf
    r = 0
    while True:
        for a in range(max(cu - r, 0), min(cu + r, kc - 1) + 1):
            whole = a == cu - r or a == cu + r             # a whole row of the ring, else its two ends
            for b in range(max(cv - r, 0), min(cv + r, kc - 1) + 1):
                if not whole and b != cv - r and b != cv + r:
                    continue
                best, covered = _scan_cell(base + a * kc + b, x, y, z, mx, my, mz, order, first, best,
                                           tol2, bound2)
                if covered:
                    return 0.0
        # the in-plane distance from the probe to every cell not visited yet
        gap = np.inf
        if cu - r > 0:
            gap = min(gap, qu - (-radius + (cu - r) * size))
        if cu + r < kc - 1:
            gap = min(gap, -radius + (cu + r + 1) * size - qu)
        if cv - r > 0:
            gap = min(gap, qv - (-radius + (cv - r) * size))
        if cv + r < kc - 1:
            gap = min(gap, -radius + (cv + r + 1) * size - qv)
        if gap == np.inf:
            break
        gap -= SLACK
        if gap > 0 and (gap * gap > best or gap * gap >= bound2):
            break
        r += 1
    if best < bound2:
        d = np.sqrt(best)
        return np.sqrt(max(d * d - tol2, 0.0))
    return np.inf


SQRT2 = np.sqrt(2.0)


@compiled
def _probe_tol(tol0: float, boundary: float) -> float:
    """patch_error._probe_tol of one probe, operation for operation."""
    ratio = boundary / tol0 if tol0 > 0 else 1.0
    return tol0 * (SQRT2 - (SQRT2 - 1.0) * min(max(ratio, 0.0), 1.0))


@compiled
def _grid_probes(first_probe: int, last_probe: int, grid: np.ndarray, g: np.ndarray, foot: np.ndarray,
                 u: np.ndarray, v: np.ndarray, sine: np.ndarray, centre: np.ndarray, shift: np.ndarray,
                 tol0: np.ndarray, size: float, mx: np.ndarray, my: np.ndarray, mz: np.ndarray,
                 order: np.ndarray, first: np.ndarray, cells: np.ndarray, coff: np.ndarray, radius: float,
                 bound2: float, out: np.ndarray) -> None:
    """The grid probes ``grid[first_probe:last_probe]`` (PatchProbes.grid_points, boundary_distance
    and _probe_tol operation for operation; ``sine`` (T, 3): boundary_distance's divisors,
    ``sqrt(max(1 - n_c^2, 1e-12))`` of each octant's normal), their values into ``out``."""
    k = len(g)
    p = np.empty(3)
    for i in range(first_probe, last_probe):
        t = grid[i] // (k * k)
        ij = grid[i] % (k * k)
        gi, gj = g[ij // k], g[ij % k]
        boundary = np.inf
        for c in range(3):
            p[c] = foot[t, c] + gi * u[t, c] + gj * v[t, c]
            dc = (size / 2.0 - abs(p[c])) / sine[t, c]
            boundary = min(boundary, dc)
        tol = _probe_tol(tol0[t], max(boundary, 0.0))
        out[i] = _nearest(t, (p[0] + centre[t, 0]) + shift[t], p[1] + centre[t, 1], p[2] + centre[t, 2], gi, gj,
                          tol, mx, my, mz, order, first, cells, coff, radius, bound2)


@compiled
def _edge_probes(first_probe: int, last_probe: int, edge_a: np.ndarray, edge_b: np.ndarray,
                 edge_poly: np.ndarray, per_edge: int, u: np.ndarray, v: np.ndarray, centre: np.ndarray,
                 shift: np.ndarray, edge_tol0: np.ndarray, mx: np.ndarray, my: np.ndarray, mz: np.ndarray,
                 order: np.ndarray, first: np.ndarray, cells: np.ndarray, coff: np.ndarray, radius: float,
                 bound2: float, out: np.ndarray) -> None:
    """The boundary probes ``first_probe:last_probe`` (PatchProbes.edge_points operation for
    operation), their values into ``out``."""
    p = np.empty(3)
    for i in range(first_probe, last_probe):
        e = i // per_edge
        s = (i % per_edge) / per_edge
        t = edge_poly[e]
        for c in range(3):
            p[c] = edge_a[e, c] + s * (edge_b[e, c] - edge_a[e, c])
        qu = p[0] * u[t, 0] + p[1] * u[t, 1] + p[2] * u[t, 2]
        qv = p[0] * v[t, 0] + p[1] * v[t, 1] + p[2] * v[t, 2]
        out[i] = _nearest(t, (p[0] + centre[t, 0]) + shift[t], p[1] + centre[t, 1], p[2] + centre[t, 2], qu, qv,
                          edge_tol0[t], mx, my, mz, order, first, cells, coff, radius, bound2)


def probe_errors(probes: PatchProbes, todo: np.ndarray, centre: np.ndarray, normal: np.ndarray, tol0: np.ndarray,
                 edge_tol0: np.ndarray, size: float, moved: np.ndarray, puv: np.ndarray, pstart: np.ndarray,
                 separation: float, bound: float, threads: int = WORKERS) -> tuple[np.ndarray, np.ndarray]:
    """sqrt(max(d^2 - tol^2, 0)) of every grid probe and every boundary probe of ``probes``
    (:class:`~model.octree.geometry.PatchProbes` of the octants ``todo``, ``centre`` and
    ``normal`` theirs, rows in ``todo`` order), as the k-d tree of :mod:`~model.octree.patch_error`
    reads them (module invariants): the octants' points ``moved`` (3, N) shifted by octant
    (``separation`` times its index), ``puv`` (2, N) in their plane, octant ``t`` of ``todo``
    owning ``pstart[t]:pstart[t + 1]``; infinite where no point is nearer than ``bound``."""
    count = np.diff(pstart)
    cells = np.clip(np.ceil(np.sqrt(count / POINTS_PER_CELL)), 1, 64).astype(np.int64)
    coff = np.r_[0, np.cumsum(cells * cells + 1)]
    mx, my, mz = (np.ascontiguousarray(a, np.float64) for a in moved)
    pu, pv = (np.ascontiguousarray(a, np.float64) for a in puv)
    pstart = np.ascontiguousarray(pstart, np.int64)
    radius = float(probes.g[-1])
    order, first = _bin(pu, pv, pstart, radius, cells, coff)
    shift = todo * separation
    centre = np.ascontiguousarray(centre)
    sine = np.sqrt(np.maximum(1.0 - np.ascontiguousarray(normal) ** 2, 1e-12))      # boundary_distance's
    grid_out = np.empty(len(probes.grid))
    n_edge = len(probes.edge_poly) * probes.per_edge
    edge_out = np.empty(n_edge)
    bound2 = bound * bound
    shared = (mx, my, mz, order, first, cells, coff, radius, bound2)

    def grid_part(a: int, b: int) -> None:
        _grid_probes(a, b, probes.grid, probes.g, probes.foot, probes.u, probes.v, sine, centre, shift, tol0,
                     size, *shared, grid_out)

    def edge_part(a: int, b: int) -> None:
        _edge_probes(a, b, probes.edge_a, probes.edge_b, probes.edge_poly, probes.per_edge, probes.u, probes.v,
                     centre, shift, edge_tol0, *shared, edge_out)

    parts = threads if len(grid_out) + n_edge >= PARALLEL_PROBES else 1
    cuts = [split(n, parts) for n in (len(grid_out), n_edge)]

    def shares(first: int, last: int) -> None:    # shares of the grid probes and of the boundary probes
        for k in range(first, last):
            grid_part(cuts[0][k], cuts[0][k + 1])
            edge_part(cuts[1][k], cuts[1][k + 1])

    run_parts(shares, parts, parts)
    return grid_out, edge_out
