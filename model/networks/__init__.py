"""Adaptive O-CNN networks (paper section 4) and the O-CNN / point-set baselines, in torch."""

from .autoencoder import ARCHS, Arch, Autoencoder
from .decoder import OctreeDecoder, TorchSteps
from .encoder import OctreeEncoder, default_channels
from .psg import PointSetDecoder, chamfer_loss

__all__ = ["ARCHS", "Arch", "Autoencoder", "OctreeDecoder", "OctreeEncoder", "PointSetDecoder",
           "TorchSteps", "chamfer_loss", "default_channels"]
