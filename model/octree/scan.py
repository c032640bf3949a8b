"""The octree a completion model reads: a partial scan framed by :func:`scan_frame`.

Training, evaluation and the service build completion inputs with :func:`scan_octree` only, so
a model sees at serving time exactly the octrees it was trained on.  The completed shape is
decoded in the same frame, which maps it back to the scan's own coordinates.
"""

from __future__ import annotations

from .build import DEFAULT_THRESHOLD, build_octree
from .octree import Octree
from .pointcloud import PointCloud, scan_frame


def scan_octree(cloud: PointCloud, depth: int, *, adaptive: bool = True, full_depth: int = 2,
                adaptive_depth: int = 4, threshold: float = DEFAULT_THRESHOLD, neighbors: bool = True) -> Octree:
    """The octree of a partial scan (validated cloud, normals given or estimated) in its scan frame."""
    return build_octree(cloud, depth, adaptive=adaptive, full_depth=full_depth, adaptive_depth=adaptive_depth,
                        threshold=threshold, neighbors=neighbors, normalization=scan_frame(cloud.points))
