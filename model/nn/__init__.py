"""Octree CNN layers in torch (paper section 4): tensors bridged from the NumPy octree, and ops."""

from .ops import (
                  ConvBnRelu,
                  DeconvBnRelu,
                  OctreeBatchNorm,
                  OctreeConv,
                  OctreeDeconv,
                  graph_capture,
                  octree_conv,
                  octree_deconv,
                  octree_max_pool,
                  octree_upsample,
)
from .tensors import LevelTensors, OctreeTensors

__all__ = ["ConvBnRelu", "DeconvBnRelu", "LevelTensors", "OctreeBatchNorm", "OctreeConv",
           "OctreeDeconv", "OctreeTensors", "graph_capture", "octree_conv", "octree_deconv",
           "octree_max_pool", "octree_upsample"]
