"""Building full (O-CNN) and patch-guided adaptive (paper section 3) octrees from oriented points.

Points are sorted once by their finest Morton key, so every octant of every depth owns a
contiguous run of points.  Point moments are summed bottom-up (one ``reduceat`` per depth), the
tree is grown top-down, and at each adaptive depth the planes and both directions of the
patch error are computed for all candidate octants at once.
"""

from __future__ import annotations

import time
from contextlib import contextmanager
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from . import keys as morton
from .errors import OctreeInputError
from .geometry import cube_polygons, fit_planes, polygon_distance, polygon_probes
from .neighbors import build_neighbors
from .octree import EMPTY, LEAF, PLANE_SCALE, SPLIT, Normalization, Octree, OctreeLevel
from .pointcloud import PointCloud, normalization_of, validate

DEFAULT_THRESHOLD = float(np.sqrt(3.0) / 2.0)
"""The paper's split threshold, in finest voxels: sqrt(3)/2 * h."""
MAX_BUILD_DEPTH = 12
_SEPARATION = 4.0
"""Offset between octants in the per-depth k-d tree: larger than any distance inside the cube."""


@dataclass
class _Moments:
    """Sums over the points of each non-empty octant of one depth (sorted by key)."""

    key: np.ndarray          # (M,) uint64
    count: np.ndarray        # (M,) int64
    sums: np.ndarray         # (12, M): x y z, xx xy xz yy yz zz, nx ny nz (coordinates - 0.5)
    start: np.ndarray        # (M,) first point (in sorted order)
    first_child: np.ndarray | None = None  # (M,) first non-empty child at depth+1
    n_children: np.ndarray | None = None   # (M,) number of non-empty children


@dataclass
class PatchErrorSettings:
    """How the patch error is measured (all lengths in cube units)."""

    threshold: float         # delta hat
    gap: float               # sampling-gap tolerance, removed in quadrature from patch->surface
    probe_spacing: float     # spacing of the probe grid laid on each patch


class _Timer:
    """Accumulates wall time per named stage."""

    def __init__(self, out: dict | None):
        self.out = out

    @contextmanager
    def __call__(self, name: str):
        t = time.perf_counter()
        yield
        if self.out is not None:
            self.out[name] = self.out.get(name, 0.0) + time.perf_counter() - t


def build_octree(cloud: PointCloud | tuple[np.ndarray, np.ndarray | None], depth: int, *,
                 adaptive: bool = True, threshold: float = DEFAULT_THRESHOLD,
                 full_depth: int = 2, adaptive_depth: int = 4,
                 neighbors: bool = True, measure_leaves: bool = False,
                 sample_spacing: float | None = None, normalization: Normalization | None = None,
                 timings: dict | None = None) -> Octree:
    """Build the octree of one oriented point cloud.

    ``threshold`` is delta hat in finest voxels (paper: sqrt(3)/2).  ``adaptive=False`` gives
    the full O-CNN octree.  ``measure_leaves`` also measures the patch error of every leaf
    (including those at the max depth), for statistics.  ``sample_spacing`` is the spacing of
    the input samples in input units (estimated when omitted); sampling gaps up to it are not
    counted as patch error.  ``normalization`` fixes the cube frame (default: the points' own
    bounding box, :func:`normalization_of`); points outside that cube are dropped.  ``timings``
    receives seconds per build stage.
    """
    timer = _Timer(timings)
    if not isinstance(depth, (int, np.integer)) or not 1 <= depth <= MAX_BUILD_DEPTH:
        raise OctreeInputError(f"depth must be an integer in [1, {MAX_BUILD_DEPTH}], got {depth!r}")
    if not 0 <= full_depth <= depth or adaptive_depth < full_depth:
        raise OctreeInputError("need 0 <= full_depth <= depth and adaptive_depth >= full_depth")
    if not np.isfinite(threshold) or threshold <= 0:
        raise OctreeInputError(f"threshold must be a positive number of voxels, got {threshold!r}")
    if not isinstance(cloud, PointCloud):
        cloud = validate(*cloud)
    norm = normalization_of(cloud.points) if normalization is None else normalization
    cube, normals = norm.to_cube(cloud.points), cloud.normals
    if normalization is not None:
        cube, normals = _inside(cube, normals)
    h_fine = 1.0 / (1 << depth)

    with timer("keys+sort"):
        pts, nrm, key = _sorted_points(cube, normals, depth)
    with timer("moments"):
        moments = _aggregate(pts, nrm, key, depth)

    settings = None
    if adaptive or measure_leaves:
        with timer("spacing"):
            spacing = (sample_spacing / norm.scale if sample_spacing is not None
                       else _estimate_spacing(pts))
        settings = PatchErrorSettings(threshold=threshold * h_fine, gap=spacing,
                                      probe_spacing=h_fine)

    levels: list[OctreeLevel] = []
    node_key = np.zeros(1, dtype=np.uint64)
    node_ne = np.zeros(1, dtype=np.int64)          # index into moments[l], -1 for empty nodes
    parent = np.full(1, -1, dtype=np.int32)
    for lv in range(depth + 1):
        mom = moments[lv]
        n = len(node_key)
        nonempty = node_ne >= 0
        ne = node_ne[nonempty]
        size = 1.0 / (1 << lv)
        plane = np.zeros((n, 4), dtype=np.float32)
        error = np.full(n, np.nan, dtype=np.float32)
        npts = np.zeros(n, dtype=np.int32)
        npts[nonempty] = mom.count[ne]
        with timer("planes"):
            sums = np.take(mom.sums, ne, axis=1)
            normal, centroid, _ = fit_planes(mom.count[ne], sums[:3], sums[3:9], sums[9:])
            centre = (morton.decode(node_key[nonempty])[0] + 0.5) * size
            offset = (normal * (centre - (centroid + 0.5))).sum(1)
            plane[nonempty, :3] = normal
            plane[nonempty, 3] = offset / (PLANE_SCALE * size)

        label = np.full(n, EMPTY, dtype=np.int8)
        if lv < full_depth:
            split = np.ones(n, dtype=bool)
        elif lv == depth:
            split = np.zeros(n, dtype=bool)
        elif lv < adaptive_depth or not adaptive:
            split = nonempty.copy()
        else:
            err = _patch_errors(pts, nrm, settings, centre, normal, offset, size,
                                mom.start[ne], mom.count[ne], exact=False, timer=timer)
            error[nonempty] = err
            split = nonempty.copy()
            split[nonempty] = err > settings.threshold
        label[nonempty] = LEAF
        label[split] = SPLIT
        if measure_leaves:
            # Leaves not measured to decide a split (full trees, the max depth) are measured here.
            sel = np.flatnonzero(np.isnan(error[nonempty]) & (label[nonempty] == LEAF))
            if len(sel):
                error[np.flatnonzero(nonempty)[sel]] = _patch_errors(
                    pts, nrm, settings, centre[sel], normal[sel], offset[sel], size,
                    mom.start[ne[sel]], mom.count[ne[sel]], exact=True, timer=timer)

        with timer("structure"):
            child = np.full(n, -1, dtype=np.int32)
            split_idx = np.flatnonzero(split)
            child[split_idx] = np.arange(len(split_idx), dtype=np.int32)
            levels.append(OctreeLevel(depth=lv, key=node_key, label=label, child=child,
                                      parent=parent, plane=plane, error=error, npoints=npts))
            if lv == depth:
                break
            node_key, node_ne = _children(node_key, node_ne, split_idx, mom, moments[lv + 1])
            parent = np.repeat(split_idx.astype(np.int32), 8)

    octree = Octree(depth=depth, levels=levels, adaptive=adaptive,
                    threshold=threshold * h_fine, full_depth=full_depth,
                    adaptive_depth=adaptive_depth, normalizations=[norm])
    if neighbors:
        with timer("neighbors"):
            build_neighbors(octree)
    return octree


def _inside(cube: np.ndarray, normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The points (cube coordinates) and normals inside the unit cube (at least 3, or OctreeInputError)."""
    keep = ((cube >= 0) & (cube < 1)).all(1)
    if keep.sum() < 3:
        raise OctreeInputError(f"only {int(keep.sum())} of {len(cube)} points lie inside the given frame")
    return (cube, normals) if keep.all() else (cube[keep], normals[keep])


def _sorted_points(cube: np.ndarray, normals: np.ndarray, depth: int):
    """Points, normals and finest keys sorted by key."""
    res = 1 << depth
    ijk = np.clip((cube * res).astype(np.int64), 0, res - 1)
    key = morton.encode(ijk)
    order = np.argsort(key)              # the order of points inside one voxel does not matter
    return cube[order], normals[order], key[order]


def _aggregate(pts: np.ndarray, nrm: np.ndarray, key: np.ndarray, depth: int) -> list[_Moments]:
    """Point moments of every non-empty octant at every depth, finest first, then upward.

    Sums are taken segment by segment (not as differences of prefix sums), so a one-point
    octant has exactly zero spread at any depth.
    """
    # Rows x y z, xx xy xz yy yz zz, nx ny nz of every point (coordinates - 0.5 for precision).
    cols = np.empty((12, len(pts)))
    np.subtract(pts.T, 0.5, out=cols[:3])
    x, y, z = cols[0], cols[1], cols[2]
    for row, (a, b) in enumerate(((x, x), (x, y), (x, z), (y, y), (y, z), (z, z)), start=3):
        np.multiply(a, b, out=cols[row])
    cols[9:] = nrm.T
    starts = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    count = np.diff(np.r_[starts, len(key)])
    levels: list[_Moments | None] = [None] * (depth + 1)
    levels[depth] = _Moments(key=key[starts], count=count,
                             sums=np.add.reduceat(cols, starts, axis=1), start=starts)
    for lv in range(depth - 1, -1, -1):
        fine = levels[lv + 1]
        pk = fine.key >> np.uint64(3)
        first = np.flatnonzero(np.r_[True, pk[1:] != pk[:-1]])
        levels[lv] = _Moments(key=pk[first], count=np.add.reduceat(fine.count, first),
                              sums=np.add.reduceat(fine.sums, first, axis=1),
                              start=fine.start[first], first_child=first,
                              n_children=np.diff(np.r_[first, len(pk)]))
    return levels


def _children(node_key, node_ne, split_idx, mom: _Moments, fine: _Moments):
    """Keys of the 8 children of each split node and their indices into the finer moments."""
    k = len(split_idx)
    child_key = morton.child_keys(node_key[split_idx])
    child_ne = np.full(8 * k, -1, dtype=np.int64)
    parent_ne = node_ne[split_idx]
    has = parent_ne >= 0
    rank = np.flatnonzero(has)
    first = mom.first_child[parent_ne[has]]
    cnt = mom.n_children[parent_ne[has]]
    j = _ranges(first, cnt)
    slot = (fine.key[j] & np.uint64(7)).astype(np.int64)
    child_ne[8 * np.repeat(rank, cnt) + slot] = j
    return child_key, child_ne


def _ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for all pairs, without a Python loop."""
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    offs = np.cumsum(count) - count
    return np.repeat(start - offs, count) + np.arange(total)


def _estimate_spacing(pts: np.ndarray, thin_to: int = 25_000) -> float:
    """Typical sample spacing 1/sqrt(density), from nearest neighbours in a random thinning.

    A random thinning to fraction f of any point set is close to Poisson, whose mean
    nearest-neighbour distance is 1/(2 sqrt(f density)); this also avoids a tree over all points.
    """
    rng = np.random.default_rng(0)
    f = min(1.0, thin_to / len(pts))
    sub = pts[rng.random(len(pts)) < f] if f < 1.0 else pts
    if len(sub) < 2:
        return 0.0
    tree = cKDTree(sub, leafsize=16, balanced_tree=False, compact_nodes=False)
    d, _ = tree.query(sub[:: max(1, len(sub) // 4000)], k=2)
    d = d[:, 1][d[:, 1] > 0]
    return float(2.0 * d.mean() * np.sqrt(f)) if len(d) else 0.0


def _patch_errors(pts, nrm, cfg: PatchErrorSettings, centre, normal, offset,
                  size: float, start, count, *, exact: bool, timer: _Timer) -> np.ndarray:
    """Hausdorff distance between each octant's planar patch and its points (paper's delta_O).

    surface->patch: exact point-to-polygon distance of every point of the octant, plus the gap
    times the sine of the angle between the point's normal and the patch normal.
    patch->surface: distance d from probes on the patch (its boundary and a grid) to the nearest
    point of the same octant, as sqrt(d^2 - tol^2) with tol the likely largest sampling gap
    among the octant's probes, so that sampling gaps alone read as zero.  With ``exact=False``
    octants over the threshold by the first direction skip the second (they split anyway), and
    probes farther than hypot(threshold, tol) read infinite.
    """
    m = len(normal)
    with timer("error surface->patch"):
        verts, nvert = cube_polygons(normal, offset, size)
        idx = _ranges(start, count)
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
        # Each sample stands for the surface within the sampling gap around it: extrapolate its
        # distance along its own tangent plane, which leaves the patch at angle theta.
        cos = (nrm[idx] * n_o).sum(1)
        dist += cfg.gap * np.sqrt(np.maximum(1.0 - cos * cos, 0.0))
        err = np.maximum.reduceat(dist, np.cumsum(count) - count)
    with timer("error patch->surface"):
        todo = np.arange(m) if exact else np.flatnonzero(err <= cfg.threshold)
        if len(todo) == 0:
            return err
        spacing = max(cfg.probe_spacing, size / 32.0)
        probes, pid, edge_dist = polygon_probes(normal[todo], offset[todo], verts[todo],
                                                nvert[todo], size, spacing)
        oct_id = todo[pid]
        first = np.flatnonzero(np.r_[True, oct_id[1:] != oct_id[:-1]])
        n_probes = np.diff(np.r_[first, len(oct_id)])
        # Random samples leave gaps: among K probes over true surface the farthest sees its
        # nearest sample about spacing * sqrt(ln K / pi) away (Poisson statistics); the gap
        # tolerance is that distance at its 99% quantile for each octant's probe count.
        tol = np.repeat(cfg.gap * np.sqrt(np.log(100.0 * n_probes) / np.pi), n_probes)
        # Near the cube's boundary a probe sees samples on one side only: half the density, so
        # gaps sqrt(2) times wider.  The factor fades in over one tolerance from the boundary.
        tol *= np.sqrt(2.0) - (np.sqrt(2.0) - 1.0) * np.clip(edge_dist / tol, 0.0, 1.0)
        bound = np.inf if exact else float(np.hypot(cfg.threshold, tol.max()))
        d = _nearest_in_octant(pts, idx, owner, probes + centre[oct_id], oct_id, bound)
        # Removing the tolerance in quadrature forgives gaps without hiding real overhangs.
        ps = np.sqrt(np.maximum(d * d - tol * tol, 0.0))
        err[oct_id[first]] = np.maximum(err[oct_id[first]], np.maximum.reduceat(ps, first))
    return err


def _nearest_in_octant(pts, idx, owner, query, oct_id, bound: float) -> np.ndarray:
    """Distance from each query to the nearest point of its own octant (``owner`` of ``idx``).

    Every involved octant is moved to its own place along x (octant i by i * _SEPARATION), so
    one k-d tree answers all of them and no query can reach another octant's points.
    """
    wanted = np.zeros(int(owner.max()) + 1 if len(owner) else 0, dtype=bool)
    wanted[oct_id] = True
    keep = wanted[owner]
    moved = pts[idx[keep]]
    moved[:, 0] += owner[keep] * _SEPARATION
    q = query.copy()
    q[:, 0] += oct_id * _SEPARATION
    tree = cKDTree(moved, leafsize=16, balanced_tree=False, compact_nodes=False)
    return tree.query(q, k=1, distance_upper_bound=bound, workers=-1)[0]
