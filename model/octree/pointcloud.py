"""Oriented point clouds: validation, normalisation into the octree cube, normal estimation."""

from __future__ import annotations

from collections.abc import Callable
from concurrent.futures import wait
from dataclasses import dataclass

import numpy as np

from .errors import OctreeInputError
from .geometry import bounding_box
from .jit import compiled
from .knn import nearest
from .octree import Normalization
from .orient import covariances, edges_by_weight, neighbour_graph, propagate_signs, spanning_tree
from .parallel import beside as on_spare_core
from .planes import smallest_eigenvectors

CUBE_FILL = 0.96
"""The longest bounding-box edge fills this fraction of the unit cube (a margin of 2% a side)."""


@dataclass(frozen=True)
class PointCloud:
    """Points (N, 3) float64 with unit normals (N, 3), in the input's coordinates; ``strays``: how
    many points far from the rest :func:`validate` dropped (:func:`stray_points`)."""

    points: np.ndarray
    normals: np.ndarray
    strays: int = 0

    def __len__(self) -> int:
        return len(self.points)

    def rotated(self, rotation: np.ndarray) -> PointCloud:
        """The cloud turned by the 3x3 rotation ``rotation`` (points and normals alike)."""
        return PointCloud(self.points @ rotation.T, self.normals @ rotation.T, self.strays)


STRAY_SHARE = 0.1
STRAY_GAP = 3.0
"""Points far from the rest (:func:`stray_points`): at most ``STRAY_SHARE`` of a cloud, beyond an
empty shell from radius R to ``STRAY_GAP`` R about its median point, R holding the rest.  Over the
dataset's clouds (complete and partial scans, 4,359 of them, development and held-out seeds) and
scans of the real test meshes, the largest ratio between consecutive radii among a cloud's farthest
tenth of points is 1.53; a stray reflection or a second object metres away gives hundreds."""


def stray_points(points: np.ndarray) -> np.ndarray:
    """Boolean mask of the points far from the rest of (N, 3) ``points``: sorted by their distance
    from the cloud's median point, the points beyond the first gap where the next distance is more
    than :data:`STRAY_GAP` times the last, a gap that leaves at least ``1 - STRAY_SHARE`` of the
    points inside it.  Such points (a scanner's flying pixels, a reflection, a far wall) would
    otherwise set the cube the cloud is framed in and shrink the object in it to a speck."""
    r = distances_from(np.ascontiguousarray(points, dtype=np.float64), np.median(points, axis=0))
    first = max(int(np.ceil((1 - STRAY_SHARE) * len(r))) - 1, 0)
    far = np.argpartition(r, first)[first:]               # only the farthest tenth is sorted
    far = far[np.argsort(r[far], kind="stable")]
    d = r[far]
    gaps = np.flatnonzero(d[1:] > STRAY_GAP * d[:-1])
    stray = np.zeros(len(r), bool)
    if len(gaps):
        stray[far[gaps[0] + 1:]] = True
    return stray


@compiled
def distances_from(points: np.ndarray, centre: np.ndarray) -> np.ndarray:
    """Each of ``points``' (N, 3) distance from ``centre`` (3,), in one pass: the square root of
    the coordinate differences' squares summed left to right, ``sqrt((dx dx + dy dy) + dz dz)``,
    which is what ``np.linalg.norm(points - centre, axis=1)`` computes."""
    out = np.empty(len(points))
    for i in range(len(points)):
        dx = points[i, 0] - centre[0]
        dy = points[i, 1] - centre[1]
        dz = points[i, 2] - centre[2]
        out[i] = np.sqrt((dx * dx + dy * dy) + dz * dz)
    return out


LINE_TOLERANCE = 1e-4
"""A cloud whose spread across its main direction is below this share of its spread along it is a
line (or a point): thinner than a finest voxel at any depth the build allows, and what rounding
leaves of points on a line (6 significant digits put them ~1e-6 off it).  A plane is legitimate."""


Beside = Callable[[np.ndarray], object]
"""Work on a cloud's checked points (N, 3) (strays dropped) that does not need their normals,
given to :func:`validate`: run once, on the spare core while the estimated normals are oriented
(:func:`estimate_normals`; here where the normals are given), and done when the cloud is returned.
Its result is its own to keep."""


def validate(points: np.ndarray, normals: np.ndarray | None, drop_strays: bool = True,
             beside: Beside | None = None) -> PointCloud:
    """Check shapes and values, normalise normals, drop the points far from the rest
    (:func:`stray_points`, counted in ``strays``; not with ``drop_strays=False``, for samples of a
    mesh, whose every point is its geometry); raise :class:`OctreeInputError` if unusable:
    NaN or infinite values, fewer than 3 points, or points that all lie on a line or at one spot
    within rounding (decided on the singular values of the centred cloud, :data:`LINE_TOLERANCE`).
    ``beside``: work on the checked points (:data:`Beside`)."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise OctreeInputError(f"points must be an (N, 3) array, got shape {pts.shape}")
    nrm = None if normals is None else np.asarray(normals, dtype=np.float64)
    if nrm is not None and nrm.shape != pts.shape:
        raise OctreeInputError(f"normals must have the points' shape {pts.shape}, got {nrm.shape}")
    if not np.isfinite(pts).all():
        bad = ~np.isfinite(pts).all(1)
        raise OctreeInputError(
            f"{int(bad.sum())} point(s) have NaN or infinite coordinates (first at row "
            f"{int(np.flatnonzero(bad)[0])}); remove them")
    if len(pts) < 3:
        raise OctreeInputError(f"need at least 3 points to fit a plane, got {len(pts)}")
    stray = stray_points(pts) if drop_strays else np.zeros(len(pts), bool)
    strays = int(stray.sum())
    if strays:
        pts = pts[~stray]
        nrm = None if nrm is None else nrm[~stray]
    lo, hi = bounding_box(pts)
    if (hi - lo).max() <= 1e-12 * max(1.0, float(np.abs(pts).max())):
        raise OctreeInputError(f"all points lie within {(hi - lo).max():.1e} of one another (identical within "
                               "rounding); a surface needs points spread in space")
    sub = pts[:: max(1, len(pts) // 20000)]
    spread = np.linalg.svd(sub - sub.mean(0), compute_uv=False)
    if spread[1] <= LINE_TOLERANCE * spread[0]:
        raise OctreeInputError(
            f"all points lie on a line (their spread across it is {spread[1] / spread[0]:.1e} of their spread "
            "along it); a surface needs points spread in 2 dimensions")
    if nrm is None:
        return PointCloud(pts, estimate_normals(pts, beside=beside), strays)
    if not np.isfinite(nrm).all():
        raise OctreeInputError("normals contain NaN or infinite values")
    length = np.sqrt(np.einsum("ij,ij->i", nrm, nrm))
    zero = length < 1e-12
    if zero.any():
        raise OctreeInputError(
            f"{int(zero.sum())} normal(s) have zero length (first at row {int(np.flatnonzero(zero)[0])}); "
            "give unit normals or omit normals to have them estimated")
    if beside is not None:
        beside(pts)
    return PointCloud(pts, nrm / length[:, None], strays)


def normalization_of(points: np.ndarray) -> Normalization:
    """Centre the bounding box in the unit cube and scale its longest edge to :data:`CUBE_FILL`."""
    lo, hi = bounding_box(points)
    return Normalization(center=(lo + hi) / 2.0, scale=float((hi - lo).max() / CUBE_FILL))


MIN_SCAN_POINTS = 100
"""A partial scan with fewer points (after its strays are dropped) is not completed: a handful of
points says nothing of the shape, and the service answers 400 rather than a guess."""


SCAN_FRAME_MARGIN = 1.1
"""A partial scan's frame is its bounding cube enlarged by this factor: in 99.8% of the dataset's
partial scans the complete shape lies inside it (docs/journal/2026-11-experiments.md, shape completion)."""


def scan_frame(points: np.ndarray, margin: float = SCAN_FRAME_MARGIN) -> Normalization:
    """The cube a completion model reads a partial scan in and writes the completed shape in.

    The partial's bounding box centred in the unit cube, its longest edge filling
    ``CUBE_FILL / margin`` of it, so that the missing parts fit around the observed ones.
    Training, evaluation and the service all frame scans with this one function.
    """
    if not margin >= 1:
        raise ValueError(f"margin must be at least 1, got {margin!r}")
    norm = normalization_of(points)
    return Normalization(center=norm.center, scale=norm.scale * margin)


def estimate_normals(points: np.ndarray, k: int = 16, beside: Beside | None = None) -> np.ndarray:
    """Unit normals from k-nearest-neighbour PCA, consistently oriented and pointing outward.

    Orientation follows Hoppe et al.: signs propagate along a minimum spanning tree of the kNN
    graph weighted by 1 - |n_i . n_j|; each connected part is then flipped so that most of its
    normals point away from its centroid.  The neighbours (:mod:`model.octree.knn`), the
    covariances, the tree and the walk along it are compiled (:mod:`model.octree.orient`).
    The neighbours and covariances take both cores, the orientation one: ``beside(points)`` runs
    on the other meanwhile (:data:`Beside`).
    """
    n = len(points)
    k = int(min(k, n))
    points = np.ascontiguousarray(points, dtype=np.float64)
    nn = nearest(points, k)
    cov = covariances(points, nn)
    side = None if beside is None else on_spare_core(lambda: beside(points))
    try:
        normals = _oriented(points, nn, smallest_eigenvectors(cov)[0])
    except BaseException:
        if side is not None:                  # the work beside is finished, its own error not raised:
            wait([side])                      # the orientation's is the one to see
        raise
    if side is not None:
        side.result()
    return normals


def _oriented(points: np.ndarray, nn: np.ndarray, normals: np.ndarray) -> np.ndarray:
    """:func:`estimate_normals`' orientation of ``normals`` (n, 3), each the PCA normal of its
    point's neighbours ``nn`` (n, k)."""
    n, k = nn.shape
    if k < 2:
        return normals
    rows, cols, weights = neighbour_graph(nn, normals)
    edges = edges_by_weight(weights, rows, cols)    # in the order (ties included) SciPy's Kruskal took
    del rows, cols, weights                         # (a large cloud's graph: their memory goes before the tree's)
    sign, part = propagate_signs(n, *spanning_tree(n, *edges), normals)
    normals = normals * sign[:, None]
    # Each part faces outward: most normals point away from its centroid.
    parts = int(part.max()) + 1
    count = np.bincount(part, minlength=parts)
    centroid = np.stack([np.bincount(part, points[:, a], parts) for a in range(3)], 1) / count[:, None]
    out = np.sign(((points - centroid[part]) * normals).sum(1))
    flip = np.bincount(part, out, parts) < 0
    normals[flip[part]] *= -1.0
    return normals


