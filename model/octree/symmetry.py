"""Mirror symmetry of a partial scan: what the scanner saw of one side, reflected onto the other.

Most made objects are mirror-symmetric about a vertical plane across their left-right axis
(chairs, cars, airplanes, cabinets). A completion model reads a scan upright in the shapes'
convention (+Y up, +Z front, so X runs left to right: the axis the models were trained with), so
that plane is ``x = c`` for an unknown ``c``. :func:`find_mirror` finds ``c`` as the plane across
which the most of the scan lands on itself, and reports that share (its support); a scan
supported well enough is completed from itself and its mirror image (:func:`symmetrize`), so a
side the scanner never saw starts from the geometry of the side it did. The support threshold
was chosen on the validation split (docs/RESULTS.md); an asymmetric object (a one-armed sofa, a
lamp with its arm to one side) scores lower and is left as scanned.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .pointcloud import PointCloud

MIN_SUPPORT = 0.85
"""The least support at which a scan is mirrored (:func:`symmetrize`): chosen on the validation
split among 0.80, 0.85, 0.90 and 0.95 as the one with the lowest completion Chamfer distance."""

TOLERANCE = 0.01
"""A mirrored point lands on the scan when it is within this share of the scan's bounding-box
diagonal of a scanned point."""


@dataclass(frozen=True)
class Mirror:
    """The plane ``x[axis] = offset`` (in the scan's coordinates) and its ``support``: the share
    of the scan's points off the plane (farther than two tolerances) whose mirror image lands on
    the scan, in [0, 1]."""

    axis: int
    offset: float
    support: float

    def supported(self, min_support: float = MIN_SUPPORT) -> bool:
        """Whether the scan is mirror-symmetric enough to be read with its mirror image."""
        return self.support >= min_support

    def reflect(self, points: np.ndarray) -> np.ndarray:
        """``points`` (N, 3) reflected across the plane."""
        out = np.array(points, dtype=np.float64, copy=True)
        out[:, self.axis] = 2 * self.offset - out[:, self.axis]
        return out


def _support(points: np.ndarray, tree: cKDTree, axis: int, offset: float, tol: float) -> tuple[float, np.ndarray]:
    """The support of the plane ``x[axis] = offset`` measured on ``points`` (a subset of the
    scan in ``tree``), and which of them land on the scan."""
    mirrored = points.copy()
    mirrored[:, axis] = 2 * offset - mirrored[:, axis]
    dist, _ = tree.query(mirrored, distance_upper_bound=tol)
    hit = dist < tol
    off_plane = np.abs(points[:, axis] - offset) > 2 * tol        # a point on the plane is its own image
    return (float(hit[off_plane].mean()) if off_plane.any() else 0.0), hit & off_plane


def find_mirror(points: np.ndarray, axis: int = 0, tolerance: float = TOLERANCE, candidates: int = 81,
                sample: int = 3000, seed: int = 0) -> Mirror:
    """The plane ``x[axis] = c`` across which the scan ``points`` (N, 3), N >= 3, is most
    symmetric: ``candidates`` offsets across the scan's extent along ``axis`` are scored by their
    support (on a fixed random ``sample`` of the points), and the best is refined by moving it to
    the mean midpoint of the pairs it matches (a few rounds).  Deterministic for a given ``seed``."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise ValueError(f"points must be an (N, 3) array with N >= 3, got shape {pts.shape}")
    lo, hi = pts.min(0), pts.max(0)
    tol = tolerance * float(np.linalg.norm(hi - lo))
    if tol <= 0:
        return Mirror(axis, float(lo[axis]), 0.0)
    rng = np.random.default_rng(seed)
    sub = pts[rng.choice(len(pts), sample, replace=False)] if len(pts) > sample else pts
    tree = cKDTree(pts)
    offsets = np.linspace(lo[axis], hi[axis], candidates)
    scores = [_support(sub, tree, axis, c, tol)[0] for c in offsets]
    offset = float(offsets[int(np.argmax(scores))])
    for _ in range(5):
        mirrored = sub.copy()
        mirrored[:, axis] = 2 * offset - mirrored[:, axis]
        dist, nearest = tree.query(mirrored, distance_upper_bound=tol)
        hit = dist < tol
        if hit.sum() < 3:
            break
        step = float(np.mean(pts[nearest[hit], axis] - mirrored[hit, axis])) / 2
        offset += step
        if abs(step) < 1e-3 * tol:
            break
    return Mirror(axis, offset, _support(sub, tree, axis, offset, tol)[0])


def mirror_cloud(cloud: PointCloud, mirror: Mirror) -> PointCloud:
    """The cloud and its mirror image across ``mirror``'s plane (2N points; normals reflected)."""
    normals = np.array(cloud.normals, dtype=np.float64, copy=True)
    normals[:, mirror.axis] *= -1
    return PointCloud(np.concatenate([cloud.points, mirror.reflect(cloud.points)]),
                      np.concatenate([cloud.normals, normals]))


def symmetrize(cloud: PointCloud, min_support: float = MIN_SUPPORT, axis: int = 0) -> tuple[PointCloud, Mirror]:
    """``cloud`` with its mirror image added when the plane :func:`find_mirror` finds has at least
    ``min_support``, else ``cloud`` itself; and that plane."""
    mirror = find_mirror(cloud.points, axis=axis)
    return (mirror_cloud(cloud, mirror) if mirror.supported(min_support) else cloud), mirror
