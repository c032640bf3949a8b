"""The patch error delta_O (paper section 3): Hausdorff distance between an octant's planar patch
and the input points inside it, measured for all octants of one depth at once.

surface->patch is exact per point.  patch->surface is measured at probes laid on each patch
(:class:`model.octree.geometry.PatchProbes`).  Most probes are settled by the octant's points
binned on the patch's probe grid (a point near the probe proves it within the gap tolerance,
where it reads zero) and only the rest go to a k-d tree: the values are those of asking the k-d
tree for every probe (``tests/octree/test_build_equivalence.py`` holds this).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .geometry import PatchProbes, boundary_distance, cube_polygons, patch_probes, polygon_distance
from .segments import concat_ranges
from .timing import StageTimes

_SEPARATION = 4.0
"""Offset between octants in the per-depth k-d tree: larger than any distance inside the cube."""


@dataclass
class PatchErrorSettings:
    """How the patch error is measured (all lengths in cube units)."""

    threshold: float         # delta hat
    gap: float               # sampling-gap tolerance, removed in quadrature from patch->surface
    probe_spacing: float     # spacing of the probe grid laid on each patch


def patch_errors(pts: np.ndarray, nrm: np.ndarray, cfg: PatchErrorSettings, centre: np.ndarray,
                 normal: np.ndarray, offset: np.ndarray, size: float, start: np.ndarray,
                 count: np.ndarray, *, exact: bool, certify: bool = True, timer=None) -> np.ndarray:
    """Hausdorff distance between each octant's planar patch and its points (paper's delta_O).

    surface->patch: exact point-to-polygon distance of every point of the octant, plus the gap
    times the sine of the angle between the point's normal and the patch normal.
    patch->surface: distance d from probes on the patch (its boundary and a grid) to the nearest
    point of the same octant, as sqrt(d^2 - tol^2) with tol the likely largest sampling gap
    among the octant's probes, so that sampling gaps alone read as zero.  With ``exact=False``
    octants over the threshold by the first direction skip the second (they split anyway), and
    probes farther than hypot(threshold, tol) read infinite.  Points and normals are rows
    (3, N) sorted so that octant i owns columns ``start[i] .. start[i] + count[i] - 1``.

    With ``certify``, probes that the octant's points binned on the patch's probe grid prove
    within tol of a point read zero without a k-d tree query; the k-d tree would read zero for
    them too, so the values do not depend on it.
    """
    timer = timer or StageTimes(None)
    m = len(normal)
    owner = np.repeat(np.arange(m), count)
    with timer("patch polygons"):
        verts, nvert = cube_polygons(normal, offset, size)
    with timer("error surface->patch"):
        err, local, s, idx = _surface_to_patch(pts, nrm, cfg, centre, normal, offset, size, start, count, owner, verts)
    todo = np.arange(m) if exact else np.flatnonzero(err <= cfg.threshold)
    if len(todo) == 0:
        return err
    with timer("probes"):
        spacing = max(cfg.probe_spacing, size / 32.0)
        probes = patch_probes(normal[todo], offset[todo], verts[todo], nvert[todo], size, spacing)
        n_probes = (np.bincount(probes.grid_patch, minlength=len(todo))
                    + np.bincount(probes.edge_patch, minlength=len(todo)))
        # Random samples leave gaps: among K probes over true surface the farthest sees its
        # nearest sample about spacing * sqrt(ln K / pi) away (Poisson statistics); the gap
        # tolerance is that distance at its 99% quantile for each octant's probe count.
        tol0 = cfg.gap * np.sqrt(np.log(100.0 * np.maximum(n_probes, 1)) / np.pi)
        # Boundary probes lie on the cube's faces (distance 0 to the boundary, exactly).
        edge_tol0 = _probe_tol(tol0, np.zeros(len(todo)))
    grid_open, edge_open = np.arange(len(probes.grid_patch)), np.arange(len(probes.edge_patch))
    # Cells about half the gap tolerance wide let a 5x5 window reach the points that cover a
    # probe; far denser clouds than the probe grid (tolerance below a quarter cell) skip this.
    step, typical = probes.g[1] - probes.g[0], float(np.median(tol0))
    scale = 2.0 ** np.clip(np.round(np.log2(max(typical, 1e-300) / (2.0 * step))), -2, 3)
    if certify and typical >= 0.5 * step * scale:
        with timer("probes on the patch grid"):
            bins = _PatchBins.of(probes, todo, owner, local, s, m, scale)
            grid_open, edge_open = _unsettled(probes, bins, tol0, edge_tol0, normal[todo], size)
    with timer("probes in k-d tree"):
        bound = np.inf if exact else float(np.hypot(cfg.threshold, edge_tol0.max()))
        _probes_in_tree(err, pts, idx, owner, probes, todo, grid_open, edge_open, tol0, edge_tol0, centre,
                        normal, size, bound)
    return err


def _surface_to_patch(pts, nrm, cfg: PatchErrorSettings, centre, normal, offset, size: float, start, count, owner,
                      verts):
    """surface->patch of every octant (its points' largest distance to its polygon, each point's
    sampling gap extrapolated along its own tangent plane), and what the probes reuse: the points
    in their octants' local frames, their signed distances to the planes, their column indices."""
    idx = concat_ranges(start, count)
    whole = len(idx) == pts.shape[1]          # every point, in order: no gather needed
    nx, ny, nz, cx, cy, cz, off = (np.repeat(c, count) for c in (*normal.T, *centre.T, offset))
    local = [(pts[c] if whole else pts[c][idx]) - cc for c, cc in enumerate((cx, cy, cz))]
    s = local[0] * nx + local[1] * ny
    s += local[2] * nz
    s += off
    dist = np.abs(s)
    lim = size * (0.5 + 1e-9)
    outside = np.zeros(len(s), dtype=bool)
    for lc, nc in zip(local, (nx, ny, nz)):
        outside |= np.abs(lc - s * nc) > lim
    o = np.flatnonzero(outside)
    if len(o):
        oo = owner[o]
        dist[o] = polygon_distance(np.stack([lc[o] for lc in local], axis=1), normal[oo], offset[oo], verts[oo])
    # Each sample stands for the surface within the sampling gap around it: extrapolate its
    # distance along its own tangent plane, which leaves the patch at angle theta.
    nn = [nrm[c] if whole else nrm[c][idx] for c in range(3)]
    cos = nn[0] * nx + nn[1] * ny
    cos += nn[2] * nz
    dist += cfg.gap * np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    return np.maximum.reduceat(dist, np.cumsum(count) - count), local, s, idx


def _probes_in_tree(err, pts, idx, owner, probes: PatchProbes, todo, grid_open, edge_open, tol0, edge_tol0, centre,
                    normal, size: float, bound: float) -> None:
    """patch->surface of the probes not settled on the patch grid, by the k-d tree of each
    octant's points, folded into ``err`` (probes farther than ``bound`` read infinite)."""
    patch = probes.grid_patch[grid_open]
    gpts = probes.grid_points(grid_open)
    gtol = _probe_tol(tol0[patch], boundary_distance(gpts, normal[todo][patch], size))
    patch = np.concatenate([patch, probes.edge_patch[edge_open]])
    tol = np.concatenate([gtol, edge_tol0[probes.edge_patch[edge_open]]])
    query = np.concatenate([gpts, probes.edge_points(edge_open)], axis=1)
    if len(patch):
        for c in range(3):
            query[c] += centre[todo, c][patch]
        oct_id = todo[patch]
        d = _nearest_in_octant(pts, idx, owner, query, oct_id, bound)
        # Removing the tolerance in quadrature forgives gaps without hiding real overhangs.
        ps = np.sqrt(np.maximum(d * d - tol * tol, 0.0))
        np.maximum.at(err, oct_id, ps)


def _unsettled(probes: PatchProbes, bins: "_PatchBins", tol0: np.ndarray, edge_tol0: np.ndarray,
               normal: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray]:
    """Grid and boundary probes (indices) that the binned points do not prove within tolerance.

    Grid probes first try the 4 cells they are a corner of (against their octant's least
    tolerance); the rest, with their own tolerance, and the boundary probes try the 5x5 window,
    boundary probes starting from the cell one step into the patch, where the points are.
    """
    grid_patch, edge_patch = probes.grid_patch, probes.edge_patch
    grid_open = (bins.grid_uncovered(probes, tol0) if bins.scale <= 1
                 else np.arange(len(grid_patch)))
    gpatch = grid_patch[grid_open]
    gtol = _probe_tol(tol0[gpatch], boundary_distance(probes.grid_points(grid_open),
                                                      normal[gpatch], size))
    gu, gv = probes.grid_uv(grid_open)
    edge_open = np.arange(len(edge_patch))
    eu, ev, iu, iv = probes.edge_uv(edge_open)
    still = bins.uncovered(np.concatenate([gpatch, edge_patch]), np.concatenate([gu, eu]),
                           np.concatenate([gv, ev]), np.concatenate([gtol, edge_tol0[edge_patch]]),
                           centre_u=np.concatenate([gu, eu + iu * bins.cell]),
                           centre_v=np.concatenate([gv, ev + iv * bins.cell]))
    n_grid = len(grid_open)
    return grid_open[still[still < n_grid]], edge_open[still[still >= n_grid] - n_grid]


def _probe_tol(tol0: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """A probe's gap tolerance from its octant's ``tol0`` and its distance to the patch boundary.

    Near the cube's boundary a probe sees samples on one side only: half the density, so gaps
    sqrt(2) times wider.  The factor fades in over one tolerance from the boundary.
    """
    ratio = np.divide(boundary, tol0, out=np.ones_like(boundary), where=tol0 > 0)  # no gap: 0
    return tol0 * (np.sqrt(2.0) - (np.sqrt(2.0) - 1.0) * np.clip(ratio, 0.0, 1.0))


_MARGIN = 1.0 + 1e-9
"""Squared-distance bounds are inflated by this factor, so rounding never proves a probe covered."""


@dataclass
class _PatchBins:
    """The points of T octants binned on square cells of each patch's (u, v) frame.

    A point at in-plane distance c from a probe (which lies on the plane) and at height s off
    the plane is sqrt(c^2 + s^2) away from it: each cell keeps one of its points (in-plane
    coordinates and s^2, NaN for an empty cell) to prove probes near it covered.  Cells are the
    probe grid's cells split or merged by a power of 2 (``scale``), so that a 5x5 window spans
    about the gap tolerance; with ``scale <= 1`` every grid probe is a cell corner.  Each
    octant's cells carry a border of 2 empty cells, so a window never leaves its block.
    """

    kc: int                  # cells per side
    radius: float            # the cells span [-radius, radius + kc * cell) along u and v
    cell: float              # cell edge length
    scale: float             # cell / probe grid step, a power of 2
    occupied: np.ndarray     # (T, kc, kc) bool
    rep: np.ndarray          # (T * (kc + 4)^2,) complex128: float32 u, v, s^2 (and 0) of the
                             # cell's point, packed so that one gather fetches a cell
    height2: np.ndarray      # (T,) largest s^2 of the octant's points

    @classmethod
    def of(cls, probes: PatchProbes, todo: np.ndarray, owner: np.ndarray, local: list,
           s: np.ndarray, m: int, scale: float = 1.0) -> "_PatchBins":
        t_count = len(todo)
        radius = probes.g[-1]
        cell = 2.0 * radius / (probes.k - 1) * scale
        kc = int(np.ceil((probes.k - 1) / scale - 1e-9))
        rank = np.full(m, -1, dtype=np.int64)
        rank[todo] = np.arange(t_count)
        pt = rank[owner]
        if t_count < m:
            keep = np.flatnonzero(pt >= 0)
            pt = pt[keep]
            lx, ly, lz, sk = (a[keep] for a in (*local, s))
        else:
            (lx, ly, lz), sk = local, s
        counts = np.bincount(pt, minlength=t_count)
        s2 = sk * sk
        height2 = np.maximum.reduceat(s2, np.cumsum(counts) - counts)
        cid, uv = pt, []
        for axis in (probes.u, probes.v):
            w = lx * np.repeat(axis[:, 0], counts) + ly * np.repeat(axis[:, 1], counts)
            w += lz * np.repeat(axis[:, 2], counts)
            uv.append(w)
            cid = cid * (kc + 4) + 2 + np.clip(np.floor((w + radius) / cell).astype(np.int64),
                                               0, kc - 1)
        rep = np.full((t_count * (kc + 4) ** 2, 4), np.nan, dtype=np.float32)
        rep[cid, 0], rep[cid, 1], rep[cid, 2] = uv[0], uv[1], s2
        occupied = ~np.isnan(rep[:, 2].reshape(t_count, kc + 4, kc + 4)[:, 2:-2, 2:-2])
        rep = rep.view(np.complex128).ravel()
        return cls(kc=kc, radius=radius, cell=cell, scale=scale, occupied=occupied, rep=rep,
                   height2=height2)

    def grid_uncovered(self, probes: PatchProbes, tol0: np.ndarray) -> np.ndarray:
        """Grid probes not proved covered by the 4 cells they are a corner of (each point of those
        lies within a cell diagonal in the plane), against the octant's least tolerance tol0.
        Needs ``scale <= 1``, where grid probes are cell corners."""
        per = int(round(1.0 / self.scale))         # cells per probe step
        corners, t_count = self.kc + 1, len(tol0)
        pad = np.zeros((t_count, corners + 1, corners + 1), dtype=bool)
        pad[:, 1:corners, 1:corners] = self.occupied
        near = pad[:, :corners, :corners] | pad[:, 1:, :corners]
        near |= pad[:, :corners, 1:]
        near |= pad[:, 1:, 1:]
        near = near[:, ::per, ::per]                 # the corners that are grid points
        diag2 = 2.0 * max(np.diff(probes.g).max(), self.cell * per) ** 2 / per ** 2
        cheap = (diag2 + self.height2) * _MARGIN <= tol0 * tol0
        ok = near.ravel()[probes.grid]
        ok &= cheap[probes.grid_patch]
        return np.flatnonzero(~ok)

    def uncovered(self, patch: np.ndarray, wu: np.ndarray, wv: np.ndarray, tol: np.ndarray,
                  centre_u: np.ndarray | None = None, centre_v: np.ndarray | None = None
                  ) -> np.ndarray:
        """Probes (patch, in-plane coordinates, tolerance) with no kept point within tol among
        the cells of the 5x5 window (nearest cells first) around the probe's cell, or around the
        cell of ``centre`` (a point near the probe on the side where points are expected)."""
        kc, side = self.kc, self.kc + 4
        cell = patch
        for w, c in ((wu, centre_u), (wv, centre_v)):
            ci = np.floor(((w if c is None else c) + self.radius) / self.cell).astype(np.int64)
            cell = cell * side + 2 + np.clip(ci, 0, kc - 1)
        wu, wv = wu.astype(np.float32), wv.astype(np.float32)
        # float32 coordinates (|w| <= radius) err by radius * 2^-24 each, and the arithmetic by
        # 2^-24 relative: d^2 is off by at most (8 radius / tol + 7) 2^-24 of tol^2.  Twice that
        # comes off tol^2, so rounding never proves a probe covered.
        rel = 2.0 * (8.0 * self.radius / tol + 7.0) * 2.0 ** -24
        tol2 = (tol * tol * np.maximum(1.0 - rel, 0.0)).astype(np.float32)
        open_ = np.arange(len(patch))
        for du, dv in _WINDOW:
            if len(open_) == 0:
                break
            r = np.take(self.rep, cell[open_] + (du * side + dv)).view(np.float32).reshape(-1, 4)
            a = wu[open_] - r[:, 0]
            b = wv[open_] - r[:, 1]
            d2 = a * a + b * b
            d2 += r[:, 2]
            open_ = open_[~(d2 <= tol2[open_])]
        return open_


_WINDOW = sorted(((du, dv) for du in range(-2, 3) for dv in range(-2, 3)),
                 key=lambda o: (o[0] ** 2 + o[1] ** 2, o))
"""Cell offsets around a probe's cell, nearest first."""


def _nearest_in_octant(pts, idx, owner, query, oct_id, bound: float) -> np.ndarray:
    """Distance from each query (rows (3, P)) to the nearest point (rows (3, N)) of its own
    octant (``owner`` of ``idx``).

    Every involved octant is moved to its own place along x (octant i by i * _SEPARATION), so
    one k-d tree answers all of them and no query can reach another octant's points.
    """
    wanted = np.zeros(int(owner.max()) + 1 if len(owner) else 0, dtype=bool)
    wanted[oct_id] = True
    keep = wanted[owner]
    moved = np.take(pts, idx[keep], axis=1).T.copy()
    moved[:, 0] += owner[keep] * _SEPARATION
    q = query.T.copy()
    q[:, 0] += oct_id * _SEPARATION
    tree = cKDTree(moved, leafsize=16, balanced_tree=False, compact_nodes=False)
    return tree.query(q, k=1, distance_upper_bound=bound)[0]   # one thread: builds run side by side
