"""Shape from a single image (paper section 5.3): an image encoder and a shape decoder.

The decoder is the Adaptive O-CNN decoder (the product) or one of the paper's two comparison
rows, a PointSetGen-style point decoder and an AtlasNet-style patch decoder, all behind the
same image encoder and trained end to end with the autoencoders' losses.  Alternatively the
encoder alone is regressed onto a trained autoencoder's latent codes and the autoencoder's
decoder is used as it is (:meth:`ImageToShape.adopt_decoder`).
"""

from __future__ import annotations

import torch
from torch import nn

from ..nn.tensors import OctreeTensors
from .atlasnet import AtlasNetDecoder
from .autoencoder import shape_losses
from .decoder import PAPER_HIDDEN, OctreeDecoder
from .encoder import default_channels
from .image_encoders import image_encoder
from .psg import PointSetDecoder

IMAGE_DECODERS = ("aocnn", "psg", "atlasnet")


class ImageToShape(nn.Module):
    """``encoder`` (resnet18 | lenet) + ``decoder`` (:data:`IMAGE_DECODERS`), with its loss."""

    def __init__(self, encoder: str, decoder: str, depth: int, latent: int = 128, base_channels: int = 8,
                 top_channels: int = 64, encoder_width: int | None = None, hidden: int = PAPER_HIDDEN,
                 structure_loss: str = "ce", decoder_blocks: int = 1):
        super().__init__()
        if decoder not in IMAGE_DECODERS:
            raise ValueError(f"unknown decoder {decoder!r}; choose from {', '.join(IMAGE_DECODERS)}")
        self.depth, self.decoder_name = depth, decoder
        self.encoder = image_encoder(encoder, latent, encoder_width)
        if decoder == "aocnn":
            ch = default_channels(depth, base_channels, top_channels)
            self.decoder: nn.Module = OctreeDecoder(depth, ch, latent, mode="adaptive", hidden=hidden,
                                                    loss=structure_loss, blocks=decoder_blocks)
        elif decoder == "psg":
            self.decoder = PointSetDecoder(latent)
        else:
            self.decoder = AtlasNetDecoder(latent)

    def adopt_decoder(self, decoder: nn.Module) -> None:
        """Take a trained autoencoder's decoder weights and freeze them (latent regression)."""
        self.decoder.load_state_dict(decoder.state_dict())
        for p in self.decoder.parameters():
            p.requires_grad_(False)

    def forward(self, images: torch.Tensor, octree: OctreeTensors | None = None,
                points: torch.Tensor | None = None, latent: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Losses on a batch: images (B, 3, S, S) and the target octree and points (B, M, 3), or
        with ``latent`` (B, L) the teacher's codes: then the mean squared latent error only."""
        if latent is not None:
            loss = ((self.encoder(images) - latent) ** 2).sum(1).mean()
            return {"latent": loss, "total": loss}
        return shape_losses(self.decoder, self.encoder(images), octree, points)
