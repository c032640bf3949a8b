"""The patch-guided adaptive octree (paper section 3): NumPy/SciPy only, shared by training and serving."""

from .build import DEFAULT_THRESHOLD, build_octree
from .errors import OctreeInputError
from .octree import EMPTY, LEAF, SPLIT, Normalization, Octree, OctreeLevel
from .pointcloud import PointCloud, estimate_normals, scan_frame, validate
from .scan import scan_octree

__all__ = ["DEFAULT_THRESHOLD", "EMPTY", "LEAF", "SPLIT", "Normalization", "Octree",
           "OctreeInputError", "OctreeLevel", "PointCloud", "build_octree", "estimate_normals",
           "scan_frame", "scan_octree", "validate"]
