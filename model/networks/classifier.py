"""Shape classification (paper section 5.1): an octree encoder and a dropout + FC head.

``aocnn`` reads the adaptive octree with the plane signal at every depth (Adaptive O-CNN);
``ocnn`` reads the full octree with the signal at the finest depth only (O-CNN), as the
paper's Table 1 compares them.  The encoder ends in a 128-d code (the autoencoders' encoder),
the head is the O-CNN classification setting's dropout and fully connected layer.
"""

from __future__ import annotations

import torch
from torch import nn

from ..nn.tensors import OctreeTensors
from .encoder import OctreeEncoder, default_channels

CLASSIFIER_ARCHS = {"aocnn": ("adaptive", "all"), "ocnn": ("full", "finest")}
"""Classifier architecture -> (octree it reads, encoder signal)."""


class Classifier(nn.Module):
    """Octree (B shapes) -> class logits (B, classes), with the cross-entropy loss as forward."""

    def __init__(self, arch: str, depth: int, classes: int, latent: int = 128, base_channels: int = 8,
                 top_channels: int = 64, dropout: float = 0.5):
        super().__init__()
        if arch not in CLASSIFIER_ARCHS:
            raise ValueError(f"unknown arch {arch!r}; choose from {', '.join(CLASSIFIER_ARCHS)}")
        self.arch_name, self.depth, self.classes = arch, depth, classes
        ch = default_channels(depth, base_channels, top_channels)
        self.encoder = OctreeEncoder(depth, ch, latent, signal=CLASSIFIER_ARCHS[arch][1])
        self.head = nn.Sequential(nn.Dropout(dropout), nn.Linear(latent, classes))

    def logits(self, octree: OctreeTensors) -> torch.Tensor:
        return self.head(self.encoder(octree))

    def forward(self, octree: OctreeTensors, labels: torch.Tensor) -> dict[str, torch.Tensor]:
        """Cross-entropy (``total``) and accuracy of a batch; ``labels`` (B,) class indices."""
        z = self.logits(octree)
        loss = nn.functional.cross_entropy(z, labels)
        return {"cross_entropy": loss, "accuracy": (z.argmax(1) == labels).float().mean().detach(), "total": loss}
