"""Adaptive O-CNN networks (paper section 4) and the O-CNN / point-set baselines, in torch."""

from .atlasnet import AtlasNetDecoder
from .autoencoder import ARCHS, Arch, Autoencoder, shape_losses
from .classifier import CLASSIFIER_ARCHS, Classifier
from .decoder import OctreeDecoder, TorchSteps
from .encoder import OctreeEncoder, default_channels
from .image_encoders import IMAGE_ENCODERS, LeNet, ResNet18, image_encoder
from .image_to_shape import IMAGE_DECODERS, ImageToShape
from .psg import PointSetDecoder, chamfer_loss

__all__ = ["ARCHS", "Arch", "AtlasNetDecoder", "Autoencoder", "CLASSIFIER_ARCHS", "Classifier", "IMAGE_DECODERS",
           "IMAGE_ENCODERS",
           "ImageToShape", "LeNet", "OctreeDecoder", "OctreeEncoder", "PointSetDecoder", "ResNet18",
           "TorchSteps", "chamfer_loss", "default_channels", "image_encoder", "shape_losses"]
