"""Adaptive O-CNN: the patch-guided adaptive octree, its networks, data and training."""
