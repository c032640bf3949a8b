"""Building full (O-CNN) and patch-guided adaptive (paper section 3) octrees from oriented points.

Points are sorted once by their finest Morton key, so every octant of every depth owns a
contiguous run of points.  Point moments are summed bottom-up (one segment sum per depth), the
tree is grown top-down, and at each adaptive depth the planes and both directions of the
patch error (:mod:`model.octree.patch_error`) are computed for all candidate octants at once.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import keys as morton
from .errors import OctreeInputError
from .jit import compiled
from .knn import nearest_distances
from .neighbors import build_neighbors
from .octree import EMPTY, LEAF, PLANE_SCALE, SPLIT, Normalization, Octree, OctreeLevel
from .orient import radix_order
from .parallel import WORKERS
from .patch_error import PatchErrorSettings, patch_errors
from .planes import fit_planes
from .pointcloud import PointCloud, normalization_of, validate
from .segments import concat_ranges, segment_sums
from .timing import StageTimes

DEFAULT_THRESHOLD = float(np.sqrt(3.0) / 2.0)
"""The paper's split threshold, in finest voxels: sqrt(3)/2 * h."""
MAX_BUILD_DEPTH = 12


@dataclass
class _Moments:
    """Sums over the points of each non-empty octant of one depth (sorted by key)."""

    key: np.ndarray          # (M,) uint64
    count: np.ndarray        # (M,) int64
    sums: np.ndarray         # (12, M): x y z, xx xy xz yy yz zz, nx ny nz (coordinates - 0.5)
    start: np.ndarray        # (M,) first point (in sorted order)
    first_child: np.ndarray | None = None  # (M,) first non-empty child at depth+1
    n_children: np.ndarray | None = None   # (M,) number of non-empty children


def build_octree(cloud: PointCloud | tuple[np.ndarray, np.ndarray | None], depth: int, *,
                 adaptive: bool = True, threshold: float = DEFAULT_THRESHOLD,
                 full_depth: int = 2, adaptive_depth: int = 4,
                 neighbors: bool = True, measure_leaves: bool = False,
                 sample_spacing: float | None = None, normalization: Normalization | None = None,
                 probe_search: bool = True, timings: dict | None = None,
                 placement: Placement | None = None) -> Octree:
    """Build the octree of one oriented point cloud.

    ``threshold`` is delta hat in finest voxels (paper: sqrt(3)/2).  ``adaptive=False`` gives
    the full O-CNN octree.  ``measure_leaves`` also measures the patch error of every leaf
    (including those at the max depth), for statistics.  ``sample_spacing`` is the spacing of
    the input samples in input units (estimated when omitted); sampling gaps up to it are not
    counted as patch error.  ``normalization`` fixes the cube frame (default: the points' own
    bounding box, :func:`normalization_of`); points outside that cube are dropped.
    ``probe_search=False`` answers every patch->surface probe with a k-d tree instead of the
    search on each patch's plane (the reference: the same octree, slower).
    ``timings`` receives seconds per build stage.  ``placement``: the points already placed in the
    cube with these settings (:func:`place_points`: e.g. beside the normals' estimation).
    """
    timer = StageTimes(timings)
    _check_settings(depth, full_depth, adaptive_depth, threshold)
    if not isinstance(cloud, PointCloud):
        cloud = validate(*cloud)
    measured = adaptive or measure_leaves
    if placement is None:
        placement = place_points(cloud.points, depth, normalization, measured, sample_spacing, timer)
    else:
        placement.check(cloud.points, depth, normalization, measured, sample_spacing)
    norm, pts, key = placement.normalization, placement.pts, placement.key
    h_fine = 1.0 / (1 << depth)

    with timer("keys+sort"):
        nrm = placement.normals_in_order(cloud.normals)
    with timer("moments"):
        moments = _aggregate(pts, nrm, key, depth)
    settings = None
    if measured:
        settings = PatchErrorSettings(threshold=threshold * h_fine, gap=placement.spacing, probe_spacing=h_fine)
    rule = _SplitRule(depth, full_depth, adaptive_depth, adaptive, measure_leaves, probe_search, settings)

    levels: list[OctreeLevel] = []
    node_key = np.zeros(1, dtype=np.uint64)
    node_ne = np.zeros(1, dtype=np.int64)          # index into moments[l], -1 for empty nodes
    parent = np.full(1, -1, dtype=np.int32)
    for lv in range(depth + 1):
        level, split_idx = _level(lv, node_key, node_ne, parent, moments[lv], pts, nrm, rule, timer)
        levels.append(level)
        if lv == depth:
            break
        with timer("structure"):
            node_key, node_ne = _children(node_key, node_ne, split_idx, moments[lv], moments[lv + 1])
            parent = np.repeat(split_idx.astype(np.int32), 8)

    octree = Octree(depth=depth, levels=levels, adaptive=adaptive,
                    threshold=threshold * h_fine, full_depth=full_depth,
                    adaptive_depth=adaptive_depth, normalizations=[norm])
    if neighbors:
        with timer("neighbors"):
            build_neighbors(octree)
    return octree


def _check_settings(depth, full_depth: int, adaptive_depth: int, threshold: float) -> None:
    if not isinstance(depth, (int, np.integer)) or not 1 <= depth <= MAX_BUILD_DEPTH:
        raise OctreeInputError(f"depth must be an integer in [1, {MAX_BUILD_DEPTH}], got {depth!r}")
    if not 0 <= full_depth <= depth or adaptive_depth < full_depth:
        raise OctreeInputError("need 0 <= full_depth <= depth and adaptive_depth >= full_depth")
    if not np.isfinite(threshold) or threshold <= 0:
        raise OctreeInputError(f"threshold must be a positive number of voxels, got {threshold!r}")


@dataclass(frozen=True)
class _SplitRule:
    """Which octants a build splits: all above ``full_depth``, none at ``depth``, every non-empty
    one above ``adaptive_depth`` (or in a full octree), else those whose patch error exceeds the
    threshold of ``settings``; ``measure_leaves``: leaves not measured to decide are measured."""

    depth: int
    full_depth: int
    adaptive_depth: int
    adaptive: bool
    measure_leaves: bool
    probe_search: bool
    settings: PatchErrorSettings | None


def _level(lv: int, node_key: np.ndarray, node_ne: np.ndarray, parent: np.ndarray, mom: _Moments, pts: np.ndarray,
           nrm: np.ndarray, rule: _SplitRule, timer: StageTimes) -> tuple[OctreeLevel, np.ndarray]:
    """One depth of the build: every octant's plane fitted from its points' moments, its patch
    error measured where the rule needs it, its label; and the octants split (indices)."""
    n = len(node_key)
    nonempty = node_ne >= 0
    ne = node_ne[nonempty]
    size = 1.0 / (1 << lv)
    plane = np.zeros((n, 4), dtype=np.float32)
    error = np.full(n, np.nan, dtype=np.float32)
    npts = np.zeros(n, dtype=np.int32)
    npts[nonempty] = mom.count[ne]
    with timer("planes"):
        # every non-empty octant of the depth, in key order: the moments as they are
        sums = mom.sums if len(ne) == len(mom.key) else np.take(mom.sums, ne, axis=1)
        normal, centroid, _ = fit_planes(mom.count[ne], sums[:3], sums[3:9], sums[9:])
        centre, offset = np.empty((len(ne), 3)), np.empty(len(ne))
        _place_planes(node_key, nonempty, normal, centroid, size, PLANE_SCALE * size, centre, offset, plane)
    if lv < rule.full_depth:
        split = np.ones(n, dtype=bool)
    elif lv == rule.depth:
        split = np.zeros(n, dtype=bool)
    elif lv < rule.adaptive_depth or not rule.adaptive:
        split = nonempty.copy()
    else:
        err = patch_errors(pts, nrm, rule.settings, centre, normal, offset, size, mom.start[ne], mom.count[ne],
                           exact=False, probe_search=rule.probe_search, timer=timer)
        error[nonempty] = err
        split = nonempty.copy()
        split[nonempty] = err > rule.settings.threshold
    label = np.full(n, EMPTY, dtype=np.int8)
    label[nonempty] = LEAF
    label[split] = SPLIT
    if rule.measure_leaves:
        # Leaves not measured to decide a split (full trees, the max depth) are measured here.
        sel = np.flatnonzero(np.isnan(error[nonempty]) & (label[nonempty] == LEAF))
        if len(sel):
            error[np.flatnonzero(nonempty)[sel]] = patch_errors(
                pts, nrm, rule.settings, centre[sel], normal[sel], offset[sel], size,
                mom.start[ne[sel]], mom.count[ne[sel]], exact=True, probe_search=rule.probe_search, timer=timer)
    with timer("structure"):
        child = np.full(n, -1, dtype=np.int32)
        split_idx = np.flatnonzero(split)
        child[split_idx] = np.arange(len(split_idx), dtype=np.int32)
        level = OctreeLevel(depth=lv, key=node_key, label=label, child=child, parent=parent, plane=plane,
                            error=error, npoints=npts)
    return level, split_idx


PLACEMENT_PROBES = 1024
"""About this many of a cloud's points are kept with its :class:`Placement` to tell it from
another cloud's (:meth:`Placement.check`)."""


@dataclass(frozen=True, eq=False)
class Placement:
    """A cloud's points placed in an octree's cube, the first step of :func:`build_octree`, which
    needs the points only (so it can run before their normals are known): the cube's frame, the
    points it keeps (``inside``, of the cloud's ``count``; None: all), their stable order by
    finest key (``order``, into the kept points), their cube coordinates as rows (3, M) and keys in
    that order, and the sampling spacing in cube units (None: not asked for).  ``probes``: every
    :func:`probe_step`-th of the cloud's points, as given."""

    depth: int
    normalization: Normalization
    framed: bool                 # the frame was given (not the points' own bounding box)
    count: int
    probes: np.ndarray
    inside: np.ndarray | None
    order: np.ndarray
    pts: np.ndarray
    key: np.ndarray
    spacing: float | None
    sample_spacing: float | None

    def normals_in_order(self, normals: np.ndarray) -> np.ndarray:
        """The cloud's normals (count, 3) as rows (3, M) in the points' order."""
        nrm = np.ascontiguousarray(normals, dtype=np.float64)
        return _rows_in_order(nrm if self.inside is None else nrm[self.inside], self.order)

    def check(self, points: np.ndarray, depth: int, normalization: Normalization | None, spacing: bool,
              sample_spacing: float | None) -> None:
        """Raise ValueError unless this placement is what :func:`place_points` gives with these
        arguments: the points compared by their count and by :data:`PLACEMENT_PROBES` of them
        spread over the cloud (a cloud reordered, moved or turned is told apart; two clouds equal
        at every probe are not), the frame by value."""
        frame = self.normalization
        same = (len(points) == self.count and depth == self.depth and (normalization is not None) == self.framed
                and sample_spacing == self.sample_spacing and (self.spacing is not None or not spacing)
                and np.array_equal(np.asarray(points)[::probe_step(self.count)], self.probes)
                and (normalization is None or (np.array_equal(normalization.center, frame.center)
                                               and normalization.scale == frame.scale)))
        if not same:
            raise ValueError("the placement was made for other points, depth, frame or spacing")


def probe_step(count: int) -> int:
    """The stride of the points a :class:`Placement` keeps to check a cloud by."""
    return max(1, count // PLACEMENT_PROBES)


def place_points(points: np.ndarray, depth: int, normalization: Normalization | None = None, spacing: bool = True,
                 sample_spacing: float | None = None, timer: StageTimes | None = None,
                 threads: int = WORKERS) -> Placement:
    """``points`` (N, 3) placed in the cube of an octree of ``depth`` (:class:`Placement`): in
    ``normalization``'s frame, dropping the points outside it (at least 3 must stay, or
    OctreeInputError), or in their bounding box's (:func:`normalization_of`); the spacing
    ``sample_spacing`` (input units) or estimated (:func:`_estimate_spacing`, its queries on
    ``threads`` threads: 1 where the placement runs beside other work) when ``spacing``."""
    timer = timer or StageTimes(None)
    norm = normalization_of(points) if normalization is None else normalization
    cube = norm.to_cube(points)
    inside = None
    if normalization is not None:
        keep = ((cube >= 0) & (cube < 1)).all(1)
        if keep.sum() < 3:
            raise OctreeInputError(f"only {int(keep.sum())} of {len(cube)} points lie inside the given frame")
        if not keep.all():
            cube, inside = cube[keep], keep
    with timer("keys+sort"):
        cube = np.ascontiguousarray(cube, dtype=np.float64)
        key = morton.cell_keys(cube, 1 << depth)
        # The order of points inside a voxel is part of the result: it sets the rounding of the sums
        # and which points the spacing estimate's thinning keeps.  A stable sort keeps the input's
        # order there on every machine (the default sort's tie order depends on the CPU's SIMD
        # level: with and without AVX-512 it gave other planes, and other labels near the threshold).
        order = radix_order(key)                  # np.argsort(key, kind="stable"), 3x faster
        pts, key = _rows_in_order(cube, order), key[order]
    found = None
    if spacing:
        with timer("spacing"):
            found = sample_spacing / norm.scale if sample_spacing is not None else _estimate_spacing(pts.T, threads)
    probes = np.array(np.asarray(points)[::probe_step(len(points))], dtype=np.float64)
    return Placement(depth, norm, normalization is not None, len(points), probes, inside, order, pts, key, found,
                     sample_spacing)


@compiled
def _rows_in_order(rows: np.ndarray, order: np.ndarray) -> np.ndarray:
    """``rows.T[:, order]`` of an (N, 3) array: rows (3, N), in one pass."""
    n = len(order)
    out = np.empty((3, n))
    for j in range(n):
        i = order[j]
        for a in range(3):
            out[a, j] = rows[i, a]
    return out


def _aggregate(pts: np.ndarray, nrm: np.ndarray, key: np.ndarray, depth: int) -> list[_Moments]:
    """Point moments (from rows (3, N)) of every non-empty octant at every depth, finest first.

    Sums are taken segment by segment (not as differences of prefix sums), so a one-point
    octant has exactly zero spread at any depth.
    """
    # Rows x y z, xx xy xz yy yz zz, nx ny nz of every point (coordinates - 0.5 for precision).
    cols = np.empty((12, pts.shape[1]))
    np.subtract(pts, 0.5, out=cols[:3])
    x, y, z = cols[0], cols[1], cols[2]
    for row, (a, b) in enumerate(((x, x), (x, y), (x, z), (y, y), (y, z), (z, z)), start=3):
        np.multiply(a, b, out=cols[row])
    cols[9:] = nrm
    new = np.r_[True, key[1:] != key[:-1]]
    starts = np.flatnonzero(new)
    count = np.diff(np.r_[starts, len(key)])
    levels: list[_Moments | None] = [None] * (depth + 1)
    levels[depth] = _Moments(key=key[starts], count=count,
                             sums=segment_sums(cols, new, len(starts)), start=starts)
    for lv in range(depth - 1, -1, -1):
        fine = levels[lv + 1]
        pk = fine.key >> np.uint64(3)
        new = np.r_[True, pk[1:] != pk[:-1]]
        first = np.flatnonzero(new)
        levels[lv] = _Moments(key=pk[first], count=np.add.reduceat(fine.count, first),
                              sums=segment_sums(fine.sums, new, len(first)),
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
    j = concat_ranges(first, cnt)
    slot = (fine.key[j] & np.uint64(7)).astype(np.int64)
    child_ne[8 * np.repeat(rank, cnt) + slot] = j
    return child_key, child_ne


def _estimate_spacing(pts: np.ndarray, threads: int = WORKERS, thin_to: int = 25_000) -> float:
    """Typical sample spacing 1/sqrt(density), from nearest neighbours in a random thinning.

    A random thinning to fraction f of any point set is close to Poisson, whose mean
    nearest-neighbour distance is 1/(2 sqrt(f density)); this also avoids a tree over all points.
    """
    rng = np.random.default_rng(0)
    f = min(1.0, thin_to / len(pts))
    sub = pts[rng.random(len(pts)) < f] if f < 1.0 else pts
    if len(sub) < 2:
        return 0.0
    d = nearest_distances(sub, sub[:: max(1, len(sub) // 4000)], 2, threads)   # a k-d tree's distances, faster
    d = d[:, 1][d[:, 1] > 0]
    return float(2.0 * d.mean() * np.sqrt(f)) if len(d) else 0.0


@compiled
def _place_planes(node_key: np.ndarray, nonempty: np.ndarray, normal: np.ndarray, centroid: np.ndarray, size: float,
                  scale: float, centre: np.ndarray, offset: np.ndarray, plane: np.ndarray) -> None:
    """Each non-empty octant's centre (its key's coordinates + 0.5, times ``size``), its plane's
    offset from the centre ``n . (centre - (centroid + 0.5))`` and its row of ``plane`` (normal,
    offset / ``scale``, as float32), operation for operation as the NumPy formulation."""
    j = 0
    for i in range(len(node_key)):
        if not nonempty[i]:
            continue
        key = node_key[i]
        x = y = z = 0
        for b in range(16):
            x |= ((key >> (3 * b + 2)) & 1) << b
            y |= ((key >> (3 * b + 1)) & 1) << b
            z |= ((key >> (3 * b)) & 1) << b
        c0, c1, c2 = (float(x) + 0.5) * size, (float(y) + 0.5) * size, (float(z) + 0.5) * size
        n0, n1, n2 = normal[j, 0], normal[j, 1], normal[j, 2]
        off = 0.0 + n0 * (c0 - (centroid[j, 0] + 0.5))        # NumPy's sum starts at +0.0
        off += n1 * (c1 - (centroid[j, 1] + 0.5))
        off += n2 * (c2 - (centroid[j, 2] + 0.5))
        centre[j, 0], centre[j, 1], centre[j, 2] = c0, c1, c2
        offset[j] = off
        plane[i, 0], plane[i, 1], plane[i, 2] = n0, n1, n2
        plane[i, 3] = off / scale
        j += 1
