"""Mirror symmetry of a partial scan: what the scanner saw of one side, reflected onto the other.

Most made objects are mirror-symmetric about a vertical plane across their left-right axis
(chairs, cars, airplanes, cabinets). A completion model reads a scan upright in the shapes'
convention (+Y up, +Z front, so X runs left to right: the axis the models were trained with), so
that plane is ``x = c`` for an unknown ``c``. :func:`find_mirror` finds ``c`` as the plane across
which the most of the scan lands on itself, and reports that share (its support); a scan
supported well enough is completed from itself and its mirror image (:func:`symmetrize`), so a
side the scanner never saw starts from the geometry of the side it did. The support threshold
was chosen on the validation split (docs/journal/2026-11-experiments.md); an asymmetric object (a one-armed sofa, a
lamp with its arm to one side) scores lower and is left as scanned.  So is a sheet (a relief, a
sign: the scan within :data:`SHEET` tolerances of one plane): its mirror image lands on it in depth
whatever its outline, so its support tests two dimensions of three, and the models, trained on
closed solids, grow a body behind such a sheet, most when it is read with its mirror image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .geometry import bounding_box
from .jit import compiled
from .knn import NeighbourGrid
from .pointcloud import PointCloud

MIN_SUPPORT = 0.85
"""The least support at which a scan is mirrored (:func:`symmetrize`): chosen on the validation
split among 0.80, 0.85, 0.90 and 0.95 as the one with the lowest completion Chamfer distance."""

TOLERANCE = 0.01
"""A mirrored point lands on the scan when it is within this share of the scan's bounding-box
diagonal of a scanned point."""

SHEET = 1.5
"""A scan is a sheet when 95% of its points lie within this many tolerances of their best-fit plane.
A flat surface scanned with the training scans' noise (0.5% of the size) lies within about one
tolerance; of the generated shapes' scans 1 of 772 validation scans and 2 of 1,560 held-out ones
are sheets by this rule (docs/journal/2026-11-experiments.md)."""

SHORTLIST = 8
"""How many of the candidate planes with the highest approximate support (:func:`_coarse_supports`)
have it measured exactly before the best is refined.  The approximate support is a broad peak, the
exact one a sharp peak within it: 8 candidates, about a tenth of the extent around the broad
peak's top, gave the reference search's decision on all 656 validation and test scans."""


@dataclass(frozen=True)
class Mirror:
    """The plane ``x[axis] = offset`` (in the scan's coordinates) and its ``support``: the share
    of the scan's points off the plane (farther than two tolerances) whose mirror image lands on
    the scan, in [0, 1]; ``sheet``: the scan lies within :data:`SHEET` tolerances of one plane
    (never mirrored, whatever its support)."""

    axis: int
    offset: float
    support: float
    sheet: bool = False

    def supported(self, min_support: float = MIN_SUPPORT) -> bool:
        """Whether the scan is mirror-symmetric enough to be read with its mirror image."""
        return not self.sheet and self.support >= min_support

    def reflect(self, points: np.ndarray) -> np.ndarray:
        """``points`` (N, 3) reflected across the plane."""
        return _reflect(points, self.axis, self.offset)


def _reflect(points: np.ndarray, axis: int, offset: float) -> np.ndarray:
    """A float64 copy of ``points`` (N, 3) reflected across the plane ``x[axis] = offset``."""
    out = np.array(points, dtype=np.float64, copy=True)
    out[:, axis] = 2 * offset - out[:, axis]
    return out


def _support(points: np.ndarray, grid: NeighbourGrid, axis: int, offset: float, tol: float) -> float:
    """The support of the plane ``x[axis] = offset`` measured on ``points`` (a subset of the
    scan on ``grid``)."""
    hit = grid.hits(_reflect(points, axis, offset), tol)
    off_plane = np.abs(points[:, axis] - offset) > 2 * tol        # a point on the plane is its own image
    return float(hit[off_plane].mean()) if off_plane.any() else 0.0


def _supports(points: np.ndarray, grid: NeighbourGrid, axis: int, offsets: np.ndarray, tol: float) -> np.ndarray:
    """:func:`_support` of each plane ``x[axis] = offsets[k]``, every mirror image asked at once."""
    images = np.concatenate([_reflect(points, axis, c) for c in offsets])
    hit = grid.hits(images, tol).reshape(len(offsets), len(points))
    off_plane = np.abs(points[None, :, axis] - offsets[:, None]) > 2 * tol     # a point on the plane is its own image
    hit &= off_plane
    counted = off_plane.sum(1)
    return np.where(counted > 0, hit.sum(1) / np.maximum(counted, 1), 0.0)


def is_sheet(points: np.ndarray, tol: float, band: float = SHEET) -> bool:
    """Whether 95% of ``points`` (N, 3) lie within ``band`` tolerances ``tol`` of their best-fit
    plane (through their mean, normal to their least principal axis)."""
    centred = points - points.mean(0)
    normal = np.linalg.eigh(centred.T @ centred)[1][:, 0]
    return bool(np.quantile(np.abs(centred @ normal), 0.95) <= band * tol)


def _dilate(grid: np.ndarray, reach: tuple[int, int, int]) -> np.ndarray:
    """``grid`` (boolean, 3D) dilated by a box ``reach`` cells to each side along each axis."""
    for axis, r in enumerate(reach):
        out = grid.copy()
        n = grid.shape[axis]
        for shift in range(1, min(r, n - 1) + 1):
            lead = [slice(None)] * 3
            trail = [slice(None)] * 3
            lead[axis], trail[axis] = slice(shift, None), slice(None, n - shift)
            out[tuple(lead)] |= grid[tuple(trail)]
            out[tuple(trail)] |= grid[tuple(lead)]
        grid = out
    return grid


def _coarse_supports(points: np.ndarray, sample: np.ndarray, axis: int, offsets: np.ndarray,
                     tol: float) -> np.ndarray:
    """The support of each plane ``x[axis] = offsets[k]`` (evenly spaced from the scan's minimum
    along ``axis``), approximated on a voxel grid: ``sample``'s mirror images are looked up in the
    scan's occupancy, bins ``offsets``' spacing wide along ``axis`` and ``tol`` wide across it,
    dilated by the tolerance.  A plane offset ``k`` steps from the minimum maps bin ``i`` to bin
    ``2k - i - 1``, so every candidate is one gather."""
    other = [a for a in range(3) if a != axis]
    lo = bounding_box(points)[0]
    step = float(offsets[1] - offsets[0])
    bins = len(offsets)

    def cells(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        i = np.minimum(((p[:, axis] - lo[axis]) / step).astype(np.int64), bins - 1)
        jk = ((p[:, other] - lo[other]) / tol).astype(np.int64)
        return i, jk[:, 0], jk[:, 1]

    i, j, k = cells(points)
    grid = np.zeros((3 * bins, j.max() + 1, k.max() + 1), bool)     # bins of empty space each side
    grid[i + bins, j, k] = True
    grid = _dilate(grid, (int(np.ceil(tol / step)), 1, 1))
    si, sj, sk = cells(sample)
    across = np.minimum(sj, grid.shape[1] - 1) * grid.shape[2] + np.minimum(sk, grid.shape[2] - 1)
    hits, counted = np.zeros(bins, np.int64), np.zeros(bins, np.int64)
    _count_hits(grid.reshape(grid.shape[0], -1), si, across, np.ascontiguousarray(sample[:, axis]), offsets,
                2 * tol, hits, counted)
    return np.where(counted > 0, hits / np.maximum(counted, 1), 0.0)


@compiled
def _count_hits(grid, si, across, x, offsets, gap: float, hits, counted) -> None:
    """Per candidate ``k``: how many sample points lie more than ``gap`` off its plane
    (``counted``) and how many of those have their mirror image's cell occupied (``hits``); the
    image of bin ``i`` across the plane ``k`` steps from the minimum is bin ``2k - i - 1`` (the
    grid has ``bins`` rows of empty space each side)."""
    bins = len(offsets)
    for k in range(bins):
        for s in range(len(si)):
            if abs(x[s] - offsets[k]) > gap:
                counted[k] += 1
                if grid[2 * k - si[s] - 1 + bins, across[s]]:
                    hits[k] += 1


def find_mirror(points: np.ndarray, axis: int = 0, tolerance: float = TOLERANCE, candidates: int = 81,
                sample: int = 3000, seed: int = 0, shortlist: int | None = SHORTLIST) -> Mirror:
    """The plane ``x[axis] = c`` across which the scan ``points`` (N, 3), N >= 3, is most
    symmetric.  ``candidates`` offsets across the scan's extent along ``axis`` are scored by their
    support on a fixed random ``sample`` of the points: approximately on a voxel grid
    (:func:`_coarse_supports`), then exactly (nearest scanned points within the tolerance) for the
    ``shortlist`` best of them (None: every candidate exactly, the reference search, several times
    slower).  The best is refined by moving it to the mean midpoint of the pairs it matches (a few
    rounds) and its support measured exactly; whether the scan is a sheet (:func:`is_sheet`) is
    reported with it.  Deterministic for a given ``seed``."""
    pts = np.asarray(points, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) < 3:
        raise ValueError(f"points must be an (N, 3) array with N >= 3, got shape {pts.shape}")
    lo, hi = bounding_box(pts)
    tol = tolerance * float(np.linalg.norm(hi - lo))
    if tol <= 0 or hi[axis] <= lo[axis]:
        return Mirror(axis, float(lo[axis]), 0.0)
    rng = np.random.default_rng(seed)
    sub = pts[rng.choice(len(pts), sample, replace=False)] if len(pts) > sample else pts
    offsets = np.linspace(lo[axis], hi[axis], candidates)
    if shortlist is not None and shortlist < candidates:
        coarse = _coarse_supports(pts, sub, axis, offsets, tol)
        offsets = offsets[np.argsort(-coarse, kind="stable")[:max(shortlist, 1)]]
    grid = NeighbourGrid(pts)          # a k-d tree's answers, faster (model.octree.knn)
    offset = float(offsets[int(np.argmax(_supports(sub, grid, axis, offsets, tol)))])
    for _ in range(5):
        mirrored = _reflect(sub, axis, offset)
        dist, nearest = grid.nearest(mirrored, tol)
        hit = dist < tol
        if hit.sum() < 3:
            break
        step = float(np.mean(pts[nearest[hit], axis] - mirrored[hit, axis])) / 2
        offset += step
        if abs(step) < 1e-3 * tol:
            break
    return Mirror(axis, offset, _support(sub, grid, axis, offset, tol), is_sheet(pts, tol))


def mirror_points(points: np.ndarray, mirror: Mirror) -> np.ndarray:
    """The points (N, 3) and their mirror images across ``mirror``'s plane (2N, 3), in that order."""
    return np.concatenate([points, mirror.reflect(points)])


def mirror_cloud(cloud: PointCloud, mirror: Mirror) -> PointCloud:
    """The cloud and its mirror image across ``mirror``'s plane (2N points, :func:`mirror_points`;
    normals reflected)."""
    normals = np.array(cloud.normals, dtype=np.float64, copy=True)
    normals[:, mirror.axis] *= -1
    return PointCloud(mirror_points(cloud.points, mirror), np.concatenate([cloud.normals, normals]))


def symmetrize(cloud: PointCloud, min_support: float = MIN_SUPPORT, axis: int = 0,
               mirror: Mirror | None = None) -> tuple[PointCloud, Mirror]:
    """``cloud`` with its mirror image added when the plane :func:`find_mirror` finds has at least
    ``min_support``, else ``cloud`` itself; and that plane.  ``mirror``: the plane already found
    (``find_mirror(cloud.points, axis=axis)``, e.g. beside the cloud's normals), else searched here."""
    if mirror is None:
        mirror = find_mirror(cloud.points, axis=axis)
    elif mirror.axis != axis:
        raise ValueError(f"the plane given is across axis {mirror.axis}, not {axis}")
    return (mirror_cloud(cloud, mirror) if mirror.supported(min_support) else cloud), mirror
