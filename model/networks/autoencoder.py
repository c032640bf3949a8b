"""The autoencoders of paper section 5.2 as configurations of one encoder and one decoder.

``aocnn``: Adaptive O-CNN encoder and decoder on adaptive octrees.  ``ocnn-binary``,
``ocnn-patch``, ``ocnn-patch-star``: O-CNN encoder (signal at the finest depth) and the decoder
in the matching mode on full octrees (the ablation study).  ``psg``: the Adaptive O-CNN encoder
with a point-set decoder, trained with the Chamfer distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn

from ..decode import Guide
from ..nn.tensors import OctreeTensors
from ..octree import Octree
from .decoder import PAPER_HIDDEN, OctreeDecoder
from .encoder import OctreeEncoder, default_channels
from .psg import PointSetDecoder, chamfer_loss


@dataclass(frozen=True)
class Arch:
    """What an architecture reads and how it decodes."""

    octree: str          # 'adaptive' or 'full': the record's octree used as input and target
    signal: str          # encoder signal: 'all' depths or the 'finest' only
    decoder: str         # OctreeDecoder mode, or 'psg'


ARCHS: dict[str, Arch] = {
    "aocnn": Arch("adaptive", "all", "adaptive"),
    "ocnn-binary": Arch("full", "finest", "binary"),
    "ocnn-patch": Arch("full", "finest", "patch"),
    "ocnn-patch-star": Arch("full", "finest", "patch_star"),
    "psg": Arch("adaptive", "all", "psg"),
}


class Autoencoder(nn.Module):
    """Encoder + decoder of one architecture of :data:`ARCHS`, with its training loss."""

    def __init__(self, arch: str, depth: int, latent: int = 128, base_channels: int = 8,
                 top_channels: int = 64, psg_points: int = 2048, hidden: int = PAPER_HIDDEN,
                 structure_loss: str = "ce", decoder_blocks: int = 1, guided: bool = False):
        super().__init__()
        if arch not in ARCHS:
            raise ValueError(f"unknown arch {arch!r}; choose from {', '.join(ARCHS)}")
        if guided and ARCHS[arch].decoder == "psg":
            raise ValueError("output-guided skip connections need an octree decoder")
        self.arch_name, self.arch, self.depth = arch, ARCHS[arch], depth
        ch = default_channels(depth, base_channels, top_channels)
        self.encoder = OctreeEncoder(depth, ch, latent, signal=self.arch.signal)
        self.decoder: nn.Module = (PointSetDecoder(latent, psg_points) if self.arch.decoder == "psg"
                                   else OctreeDecoder(depth, ch, latent, mode=self.arch.decoder,
                                                      hidden=hidden, loss=structure_loss, blocks=decoder_blocks,
                                                      guided=guided))

    @property
    def guided(self) -> bool:
        """Whether the decoder has output-guided skip connections from the encoder."""
        return bool(getattr(self.decoder, "guided", False))

    def encode_octree(self, octree: Octree) -> tuple[torch.Tensor, Guide | None]:
        """Latent codes of a (batched) octree with neighbour tables and, for a guided decoder,
        the :class:`Guide` it decodes with (the encoder's features at every depth)."""
        tensors = OctreeTensors.from_octree(octree)
        if not self.guided:
            return self.encoder(tensors), None
        latent, features = self.encoder.features(tensors)
        return latent, Guide.of(octree, features)

    def forward(self, octree: OctreeTensors, points: torch.Tensor | None = None,
                target: OctreeTensors | None = None, rows: dict[int, torch.Tensor] | None = None
                ) -> dict[str, torch.Tensor]:
        """Losses on a batch: the input octree, for psg target points (B, M, 3), the target
        octree when it differs from the input (shape completion), and for a guided decoder each
        target octant's row among the input's octants per depth (:func:`model.decode.matched_rows`)."""
        target = octree if target is None else target
        if not self.guided:
            return shape_losses(self.decoder, self.encoder(octree), target, points)
        if rows is None:
            raise ValueError("a guided decoder trains with the rows of the target's octants among the input's")
        latent, features = self.encoder.features(octree)
        skips = {d: (features[d], rows[d]) for d in features}
        return self.decoder.loss(self.decoder(latent, target, skips), target)


def shape_losses(decoder: nn.Module, latent: torch.Tensor, octree: OctreeTensors | None,
                 points: torch.Tensor | None) -> dict[str, torch.Tensor]:
    """A decoder's training losses: structure + patch for octree decoders (against ``octree``),
    the Chamfer distance to ``points`` for point and patch-set decoders."""
    if isinstance(decoder, OctreeDecoder):
        if octree is None:
            raise ValueError("an octree decoder needs the target octree")
        return decoder.loss(decoder(latent, octree), octree)
    if points is None:
        raise ValueError("a point decoder needs target points")
    loss = chamfer_loss(decoder(latent), points)
    return {"chamfer": loss, "total": loss}
