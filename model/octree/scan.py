"""The octree a completion model reads: a partial scan framed by :func:`scan_frame`.

Training, evaluation and the service build completion inputs with :func:`scan_octree` only, so
a model sees at serving time exactly the octrees it was trained on.  The completed shape is
decoded in the same frame, which maps it back to the scan's own coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .build import DEFAULT_THRESHOLD, Placement, build_octree, place_points
from .octree import Octree
from .pointcloud import PointCloud, scan_frame
from .symmetry import MIN_SUPPORT, Mirror, find_mirror, mirror_points


def scan_octree(cloud: PointCloud, depth: int, *, adaptive: bool = True, full_depth: int = 2,
                adaptive_depth: int = 4, threshold: float = DEFAULT_THRESHOLD, neighbors: bool = True,
                placement: Placement | None = None) -> Octree:
    """The octree of a partial scan (validated cloud, normals given or estimated) in its scan frame;
    ``placement``: its points already placed there (:func:`lay_out_scan`)."""
    return build_octree(cloud, depth, adaptive=adaptive, full_depth=full_depth, adaptive_depth=adaptive_depth,
                        threshold=threshold, neighbors=neighbors, normalization=scan_frame(cloud.points),
                        placement=placement)


@dataclass(frozen=True, eq=False)
class ScanLayout:
    """What a scan's octree needs of its points alone, so that it can be found before their normals
    (beside their estimation): the mirror plane (None: not searched) and the points placed in the
    scan frame (:func:`scan_octree`'s ``placement``), with their mirror images where the plane is
    supported, as :func:`~model.octree.symmetry.symmetrize` adds them."""

    mirror: Mirror | None
    placement: Placement


def lay_out_scan(points: np.ndarray, depth: int, *, adaptive: bool = True, symmetry: bool = True,
                 min_support: float = MIN_SUPPORT) -> ScanLayout:
    """The :class:`ScanLayout` of a scan's points (N, 3) (upright, as its octree will be built),
    for an octree of ``depth`` (``adaptive``: with the sampling spacing its patch errors need), on
    one core (it runs beside the normals' orientation, which takes the other)."""
    mirror = find_mirror(points) if symmetry else None
    if mirror is not None and mirror.supported(min_support):
        points = mirror_points(points, mirror)
    return ScanLayout(mirror, place_points(points, depth, scan_frame(points), adaptive, threads=1))   # one core
