"""The patch error as first written: every probe answered by one k-d tree, nothing proved early.

A deliberately plain second implementation of ``model.octree.patch_error.patch_errors`` (the
formulation the build used before probes were settled on the patch grid), kept so that tests
can check that the fast build decides every octant the same way and measures the same delta_O.
It shares only ``cube_polygons``, ``plane_basis`` and ``polygon_distance`` with the build.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from model.octree.geometry import MAX_POLYGON, cube_polygons, plane_basis, polygon_distance


def reference_patch_errors(pts, nrm, cfg, centre, normal, offset, size, start, count, *,
                           exact, probe_search=True, timer=None):
    """Same contract as ``patch_errors`` (points as rows (3, N)); ``probe_search`` is ignored."""
    pts, nrm = pts.T, nrm.T
    m = len(normal)
    if m == 0:
        return np.zeros(0)
    verts, nvert = cube_polygons(normal, offset, size)
    idx = np.concatenate([np.arange(s, s + c) for s, c in zip(start, count)])
    owner = np.repeat(np.arange(m), count)
    local = pts[idx] - centre[owner]
    n_o = normal[owner]
    s = (local * n_o).sum(1) + offset[owner]
    dist = np.abs(s)
    proj = local - s[:, None] * n_o
    outside = (np.abs(proj) > size * (0.5 + 1e-9)).any(1)
    if outside.any():
        o = np.flatnonzero(outside)
        dist[o] = polygon_distance(local[o], n_o[o], offset[owner[o]], verts[owner[o]])
    cos = (nrm[idx] * n_o).sum(1)
    dist += cfg.gap * np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
    err = np.maximum.reduceat(dist, np.cumsum(count) - count)
    todo = np.arange(m) if exact else np.flatnonzero(err <= cfg.threshold)
    if len(todo) == 0:
        return err
    spacing = max(cfg.probe_spacing, size / 32.0)
    probes, pid, edge_dist = _probes(normal[todo], offset[todo], verts[todo], nvert[todo], size,
                                     spacing)
    oct_id = todo[pid]
    first = np.flatnonzero(np.r_[True, oct_id[1:] != oct_id[:-1]])
    n_probes = np.diff(np.r_[first, len(oct_id)])
    tol = np.repeat(cfg.gap * np.sqrt(np.log(100.0 * n_probes) / np.pi), n_probes)
    ratio = np.divide(edge_dist, tol, out=np.ones_like(edge_dist), where=tol > 0)
    tol *= np.sqrt(2.0) - (np.sqrt(2.0) - 1.0) * np.clip(ratio, 0.0, 1.0)
    bound = np.inf if exact else float(np.hypot(cfg.threshold, tol.max()))
    # every octant moved along x by 4 x its index: one tree, no query reaches another octant
    wanted = np.zeros(m, dtype=bool)
    wanted[oct_id] = True
    keep = wanted[owner]
    moved = pts[idx[keep]]
    moved[:, 0] += owner[keep] * 4.0
    q = probes + centre[oct_id]
    q[:, 0] += oct_id * 4.0
    d = cKDTree(moved).query(q, k=1, distance_upper_bound=bound)[0]
    ps = np.sqrt(np.maximum(d * d - tol * tol, 0.0))
    err[oct_id[first]] = np.maximum(err[oct_id[first]], np.maximum.reduceat(ps, first))
    return err


def _probes(normal, offset, verts, count, size, spacing):
    """Grid and boundary probes of each polygon, grouped by polygon, as (P, 3) points."""
    u, v = plane_basis(normal)
    radius = np.sqrt(3.0) / 2.0 * size
    k = int(np.ceil(2.0 * radius / spacing)) + 1
    g = np.linspace(-radius, radius, k)
    gu, gv = (a.ravel() for a in np.meshgrid(g, g, indexing="ij"))
    foot = -offset[:, None] * normal
    grid = foot[:, None] + gu[None, :, None] * u[:, None] + gv[None, :, None] * v[:, None]
    mi, gi = np.nonzero((np.abs(grid) <= size / 2.0 * (1.0 + 1e-9)).all(2))
    e = int(np.ceil(np.sqrt(2.0) * size / spacing))
    t = np.arange(e) / e
    k6 = np.arange(MAX_POLYGON)[None]
    nxt = np.where(k6 + 1 < count[:, None], k6 + 1, 0)                  # the last edge closes
    a, b = verts, np.take_along_axis(verts, nxt[:, :, None].repeat(3, 2), axis=1)
    edge = a[:, :, None] + t[None, None, :, None] * (b - a)[:, :, None]
    ei, ki = np.nonzero(np.arange(MAX_POLYGON)[None] < count[:, None])
    pts = np.concatenate([grid[mi, gi], edge[ei, ki].reshape(-1, 3)])
    idx = np.concatenate([mi, np.repeat(ei, e)])
    order = np.argsort(idx, kind="stable")
    pts, idx = pts[order], idx[order]
    sine = np.sqrt(np.maximum(1.0 - normal[idx] ** 2, 1e-12))
    edge_dist = np.maximum((size / 2.0 - np.abs(pts)) / sine, 0.0).min(1)
    return pts, idx, edge_dist
