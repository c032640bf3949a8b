"""The patch error delta_O (paper section 3): Hausdorff distance between an octant's planar patch
and the input points inside it, measured for all octants of one depth at once.

surface->patch is exact per point.  patch->surface is measured at probes laid on each patch
(:class:`model.octree.geometry.PatchProbes`): each probe's nearest point of its own octant,
searched on a grid of the patch's plane (:mod:`model.octree.probe_search`); the values are those
of asking a k-d tree of the octants' points for every probe, the reference kept here
(``probe_search=False``; ``tests/octree/test_build_equivalence.py`` holds this).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .geometry import PatchProbes, boundary_distance, cube_polygons, patch_probes, polygon_distance
from .jit import compiled
from .probe_search import probe_errors
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
                 count: np.ndarray, *, exact: bool, probe_search: bool = True, timer=None) -> np.ndarray:
    """Hausdorff distance between each octant's planar patch and its points (paper's delta_O).

    surface->patch: exact point-to-polygon distance of every point of the octant, plus the gap
    times the sine of the angle between the point's normal and the patch normal.
    patch->surface: distance d from probes on the patch (its boundary and a grid) to the nearest
    point of the same octant, as sqrt(d^2 - tol^2) with tol the likely largest sampling gap
    among the octant's probes, so that sampling gaps alone read as zero.  With ``exact=False``
    octants over the threshold by the first direction skip the second (they split anyway), and
    probes farther than hypot(threshold, tol) read infinite.  Points and normals are rows
    (3, N) sorted so that octant i owns columns ``start[i] .. start[i] + count[i] - 1``.

    With ``probe_search`` (the default), each probe's nearest point is searched on a grid of its
    patch's plane (:mod:`model.octree.probe_search`), with the k-d tree's distances bit for bit;
    ``probe_search=False`` asks the k-d tree (the reference, slower).
    """
    timer = timer or StageTimes(None)
    m = len(normal)
    owner = np.repeat(np.arange(m), count)
    with timer("patch polygons"):
        verts, nvert = cube_polygons(normal, offset, size)
    with timer("error surface->patch"):
        err, local, idx = _surface_to_patch(pts, nrm, cfg, centre, normal, offset, size, start, count, owner, verts)
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
    bound = np.inf if exact else float(np.hypot(cfg.threshold, edge_tol0.max()))
    if probe_search:
        with timer("probes searched"):
            _probes_searched(err, pts, idx, start, count, probes, todo, local, tol0, edge_tol0, centre, normal,
                             size, bound)
        return err
    with timer("probes in k-d tree"):
        _probes_in_tree(err, pts, idx, owner, probes, todo, tol0, edge_tol0, centre, normal, size, bound)
    return err


def _probes_searched(err, pts, idx, start, count, probes: PatchProbes, todo, local, tol0, edge_tol0, centre,
                     normal, size: float, bound: float) -> None:
    """patch->surface of every probe, each one's nearest point of its octant found on a grid of
    the patch's plane (:mod:`model.octree.probe_search`: the k-d tree's distances, bit for bit),
    folded into ``err`` (probes farther than ``bound`` read infinite)."""
    owned = count[todo]
    at = concat_ranges((np.cumsum(count) - count)[todo], owned)     # into idx (and local)
    moved = np.take(pts, idx[at], axis=1)      # the points of the octants measured, shifted as in the tree
    moved[0] += np.repeat(todo, owned) * _SEPARATION
    lx, ly, lz = (lc[at] for lc in local)
    puv = np.stack([lx * np.repeat(axis[:, 0], owned) + ly * np.repeat(axis[:, 1], owned)
                    + lz * np.repeat(axis[:, 2], owned) for axis in (probes.u, probes.v)])
    grid, edge = probe_errors(probes, todo, centre[todo], normal[todo], tol0, edge_tol0, size, moved, puv,
                              np.r_[0, np.cumsum(owned)], _SEPARATION, bound)
    np.maximum.at(err, todo[probes.grid_patch], grid)
    np.maximum.at(err, todo[probes.edge_patch], edge)


def _surface_to_patch(pts, nrm, cfg: PatchErrorSettings, centre, normal, offset, size: float, start, count, owner,
                      verts):
    """surface->patch of every octant (its points' largest distance to its polygon, each point's
    sampling gap extrapolated along its own tangent plane), and what the probes reuse: the points
    in their octants' local frames (3, P) and their column indices."""
    idx = concat_ranges(start, count)
    local, dist, term = np.empty((3, len(idx))), np.empty(len(idx)), np.empty(len(idx))
    outside = np.empty(len(idx), np.bool_)
    _point_distances(pts, nrm, centre, normal, offset, start, count, size * (0.5 + 1e-9), cfg.gap, local, dist,
                     term, outside)
    o = np.flatnonzero(outside)
    if len(o):
        oo = owner[o]
        dist[o] = polygon_distance(np.ascontiguousarray(local[:, o].T), normal[oo], offset[oo], verts[oo])
    dist += term
    return np.maximum.reduceat(dist, np.cumsum(count) - count), local, idx


@compiled
def _point_distances(pts, nrm, centre, normal, offset, start, count, lim: float, gap: float, local, dist, term,
                     outside) -> None:
    """Per point of each octant (in octant order): its coordinates about the octant's centre, its
    distance to the octant's plane, whether its foot on the plane leaves the cube (``lim``: half
    the side; then :func:`polygon_distance` measures it), and its sampling gap's part
    ``gap * sin(angle between its normal and the plane's)``; as the NumPy formulation computed
    them, operation for operation."""
    r = 0
    for i in range(len(start)):
        n0, n1, n2, off = normal[i, 0], normal[i, 1], normal[i, 2], offset[i]
        for col in range(start[i], start[i] + count[i]):
            l0, l1, l2 = pts[0, col] - centre[i, 0], pts[1, col] - centre[i, 1], pts[2, col] - centre[i, 2]
            s = l0 * n0 + l1 * n1
            s += l2 * n2
            s += off
            local[0, r], local[1, r], local[2, r] = l0, l1, l2
            dist[r] = abs(s)
            outside[r] = abs(l0 - s * n0) > lim or abs(l1 - s * n1) > lim or abs(l2 - s * n2) > lim
            cos = nrm[0, col] * n0 + nrm[1, col] * n1
            cos += nrm[2, col] * n2
            sin2 = 1.0 - cos * cos
            term[r] = gap * np.sqrt(sin2 if (sin2 >= 0.0 or sin2 != sin2) else 0.0)
            r += 1


def _probes_in_tree(err, pts, idx, owner, probes: PatchProbes, todo, tol0, edge_tol0, centre, normal, size: float,
                    bound: float) -> None:
    """patch->surface of every probe by the k-d tree of each octant's points (the reference),
    folded into ``err`` (probes farther than ``bound`` read infinite)."""
    patch = probes.grid_patch
    gpts = probes.grid_points(np.arange(len(patch)))
    gtol = _probe_tol(tol0[patch], boundary_distance(gpts, normal[todo][patch], size))
    tol = np.concatenate([gtol, edge_tol0[probes.edge_patch]])
    query = np.concatenate([gpts, probes.edge_points(np.arange(len(probes.edge_patch)))], axis=1)
    patch = np.concatenate([patch, probes.edge_patch])
    for c in range(3):
        query[c] += centre[todo, c][patch]
    if len(patch):
        oct_id = todo[patch]
        d = _nearest_in_octant(pts, idx, owner, query, oct_id, bound)
        # Removing the tolerance in quadrature forgives gaps without hiding real overhangs.
        ps = np.sqrt(np.maximum(d * d - tol * tol, 0.0))
        np.maximum.at(err, oct_id, ps)


def _probe_tol(tol0: np.ndarray, boundary: np.ndarray) -> np.ndarray:
    """A probe's gap tolerance from its octant's ``tol0`` and its distance to the patch boundary.

    Near the cube's boundary a probe sees samples on one side only: half the density, so gaps
    sqrt(2) times wider.  The factor fades in over one tolerance from the boundary.
    """
    ratio = np.divide(boundary, tol0, out=np.ones_like(boundary), where=tol0 > 0)  # no gap: 0
    return tol0 * (np.sqrt(2.0) - (np.sqrt(2.0) - 1.0) * np.clip(ratio, 0.0, 1.0))


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
