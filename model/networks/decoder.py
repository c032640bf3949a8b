"""Octree decoders: Adaptive O-CNN and the O-CNN(binary / patch / patch*) baselines, one class.

Paper section 4.2: from the latent code to the full depth 2, then per depth a conv block and the
prediction module (FC + BN + ReLU + FC, shared by the octants of a depth) giving the status and
the plane; octants to refine hand their features to their 8 children by a deconvolution.
Training follows the ground-truth octree (teacher forcing); inference grows the predicted one
through :func:`model.decode.decode`, for which this module provides the per-depth steps.
"""

from __future__ import annotations

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..nn.ops import ConvBnRelu, DeconvBnRelu, skip_gather
from ..nn.tensors import OctreeTensors
from ..octree import EMPTY, LEAF
from .encoder import default_channels

MODES = ("adaptive", "binary", "patch", "patch_star")
NORMAL_WEIGHT = 0.2
"""lambda of the patch loss (paper section 4.2)."""
STRUCTURE_LOSSES = ("ce", "balanced", "focal")
"""'ce': the paper's cross-entropy per depth; 'balanced': cross-entropy with each class weighted
by the inverse of its frequency among the depth's octants in the batch (every present class
counts equally); 'focal': focal loss, gamma = FOCAL_GAMMA."""
FOCAL_GAMMA = 2.0
PAPER_HIDDEN = 8
"""Hidden width of the prediction module in the paper's appendix."""


def structure_loss(logits: torch.Tensor, target: torch.Tensor, kind: str = "ce") -> torch.Tensor:
    """Status loss of one depth (see :data:`STRUCTURE_LOSSES`); mean over the octants."""
    if kind == "ce":
        return F.cross_entropy(logits, target)
    if kind == "balanced":
        counts = torch.bincount(target, minlength=logits.shape[1]).to(logits.dtype)
        weight = torch.where(counts > 0, counts.sum() / counts.clamp_min(1.0), torch.zeros_like(counts))
        return F.cross_entropy(logits, target, weight=weight)
    if kind == "focal":
        logp = F.log_softmax(logits, dim=1).gather(1, target[:, None])[:, 0]
        return -((1 - logp.exp()) ** FOCAL_GAMMA * logp).mean()
    raise ValueError(f"structure loss must be one of {STRUCTURE_LOSSES}, got {kind!r}")


class OctreeDecoder(nn.Module):
    """Latent codes -> per-depth status logits and planes over an octree.

    ``mode``: 'adaptive' (3 statuses from ``adaptive_depth``, planes on leaves from there),
    'binary' (empty / non-empty, no planes), 'patch' (planes at the max depth only),
    'patch_star' (planes at every depth from ``adaptive_depth``).  ``hidden`` is the prediction
    module's width, ``loss`` the structure loss (:data:`STRUCTURE_LOSSES`) and ``blocks`` the
    convolutions per depth; the paper's setting is ``hidden=8, loss='ce', blocks=1``.

    ``guided``: output-guided skip connections (Wang, Liu, Tong, CVPRW 2020): at every depth,
    before its convolution, each octant the decoder grows gets the encoder's features of the
    input's octant with the same key added (nothing where the input has none).  The decoder
    then needs, per depth, the encoder's features and each octant's row in them
    (:meth:`predict`'s ``skip`` and ``skip_index``; :func:`model.octree.keys.lookup`).
    """

    def __init__(self, depth: int, channels: dict[int, int] | None = None, latent: int = 128,
                 mode: str = "adaptive", full_depth: int = 2, adaptive_depth: int = 4,
                 hidden: int = PAPER_HIDDEN, loss: str = "ce", blocks: int = 1, guided: bool = False):
        super().__init__()
        if mode not in MODES:
            raise ValueError(f"mode must be one of {MODES}")
        if loss not in STRUCTURE_LOSSES:
            raise ValueError(f"structure loss must be one of {STRUCTURE_LOSSES}, got {loss!r}")
        self.depth, self.mode, self.loss_kind, self.guided = depth, mode, loss, guided
        self.full_depth, self.adaptive_depth = full_depth, adaptive_depth
        self.channels = channels or default_channels(depth, full_depth=full_depth)
        ch = self.channels
        self.fc = nn.Sequential(nn.Linear(latent, 64 * ch[full_depth]), nn.ReLU(inplace=True))
        depths = range(full_depth, depth + 1)
        self.conv = nn.ModuleDict({str(d): ConvBnRelu(ch[d], ch[d]) for d in depths})
        # blocks > 1: more convolutions per depth (a wider receptive field at the fine depths)
        self.refine = nn.ModuleDict({str(d): nn.ModuleList([ConvBnRelu(ch[d], ch[d]) for _ in range(blocks - 1)])
                                     for d in depths}) if blocks > 1 else None
        self.pred = nn.ModuleDict({str(d): nn.Sequential(
            nn.Linear(ch[d], hidden), nn.BatchNorm1d(hidden), nn.ReLU(inplace=True),
            nn.Linear(hidden, self.classes(d) + (4 if self.has_plane(d) else 0))) for d in depths})
        self.up = nn.ModuleDict({str(d): DeconvBnRelu(ch[d], ch[d + 1]) for d in range(full_depth, depth)})

    def classes(self, depth: int) -> int:
        return 3 if self.mode == "adaptive" and depth >= self.adaptive_depth else 2

    def has_plane(self, depth: int) -> bool:
        if self.mode in ("adaptive", "patch_star"):
            return depth >= self.adaptive_depth
        return self.mode == "patch" and depth == self.depth

    # -- the per-depth steps (shared by teacher forcing and model.decode.decode) --------------
    def start(self, latent: torch.Tensor) -> torch.Tensor:
        """Features (B*64, C) of the full depth-2 octants, shape-major in key order."""
        return self.fc(latent).reshape(-1, self.channels[self.full_depth])

    def predict(self, depth: int, x: torch.Tensor, neighbors: torch.Tensor, skip: torch.Tensor | None = None,
                skip_index: torch.Tensor | None = None) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor | None]:
        """One depth: (skip connection,) convolutions, status logits and planes.  ``skip`` (M, C)
        and ``skip_index`` (N,): a guided decoder's input features and each octant's row in them."""
        if self.guided:
            if skip is None or skip_index is None:
                raise ValueError("a guided decoder needs the encoder's features and their rows (skip, skip_index)")
            x = x + skip_gather(skip, skip_index)
        x = self.conv[str(depth)](x, neighbors)
        if self.refine is not None:
            for block in self.refine[str(depth)]:
                x = block(x, neighbors)
        out = self.pred[str(depth)](x)
        k = self.classes(depth)
        plane = None
        if self.has_plane(depth):
            normal = F.normalize(out[:, k:k + 3], dim=1, eps=1e-6)
            plane = torch.cat([normal, torch.tanh(out[:, k + 3:k + 4])], dim=1)
        return x, out[:, :k], plane

    def expand(self, depth: int, x: torch.Tensor, split: torch.Tensor) -> torch.Tensor:
        return self.up[str(depth)](x, split)

    def forward(self, latent: torch.Tensor, octree: OctreeTensors,
                skips: dict[int, tuple[torch.Tensor, torch.Tensor]] | None = None
                ) -> list[tuple[torch.Tensor, torch.Tensor | None]]:
        """Teacher forcing: run over the ground-truth octree; (logits, plane) per depth from 2.
        ``skips`` (guided decoders): depth -> (the encoder's features, each octant's row in them)."""
        x = self.start(latent)
        outputs = []
        for d in range(self.full_depth, self.depth + 1):
            lv = octree.levels[d]
            x, logits, plane = self.predict(d, x, lv.neighbors, *(skips or {}).get(d, (None, None)))
            outputs.append((logits, plane))
            if d < self.depth:
                x = self.expand(d, x, lv.split)
        return outputs

    def status_targets(self, depth: int, label: torch.Tensor) -> torch.Tensor:
        """Class of each ground-truth octant: non-empty (2 classes) or its label (3 classes)."""
        if self.classes(depth) == 2:
            return (label != EMPTY).long()
        return label.long()          # 0 empty, 1 split (poorly approximated), 2 leaf (well)

    def supervised(self, depth: int, label: torch.Tensor) -> torch.Tensor:
        """Octants whose plane is supervised at this depth."""
        if self.mode == "adaptive":
            return label == LEAF
        return label != EMPTY

    def loss(self, outputs, octree: OctreeTensors) -> dict[str, torch.Tensor]:
        """Structure loss (cross-entropy summed over depths) + patch loss (paper section 4.2)."""
        structure = torch.zeros((), device=outputs[0][0].device)
        patch = torch.zeros((), device=outputs[0][0].device)
        for (logits, plane), d in zip(outputs, range(self.full_depth, self.depth + 1)):
            label = octree.levels[d].label
            structure = structure + structure_loss(logits, self.status_targets(d, label), self.loss_kind)
            if plane is not None:
                sel = self.supervised(d, label)
                if bool(sel.any()):
                    target = octree.levels[d].plane[sel]
                    p = plane[sel]
                    n_err = ((p[:, :3] - target[:, :3]) ** 2).sum(1)
                    d_err = (p[:, 3] - target[:, 3]) ** 2
                    patch = patch + (NORMAL_WEIGHT * n_err + d_err).mean()
        return {"structure": structure, "patch": patch, "total": structure + patch}


def teacher_skips(guide, octree) -> dict[int, tuple[torch.Tensor, torch.Tensor]] | None:
    """A :class:`model.decode.Guide`'s skips (its features as tensors) for teacher forcing over
    ``octree`` (None: no guide)."""
    if guide is None:
        return None
    return {d: (torch.as_tensor(f), torch.from_numpy(rows)) for d, (f, rows) in guide.matched(octree).items()}


class TorchSteps:
    """Adapts an :class:`OctreeDecoder` to :class:`model.decode.DecoderSteps` (NumPy in and out)."""

    def __init__(self, decoder: OctreeDecoder, device: str = "cpu"):
        self.decoder, self.device, self.depth = decoder, device, decoder.depth

    def classes(self, depth: int) -> int:
        return self.decoder.classes(depth)

    @torch.no_grad()
    def start(self, latent: np.ndarray) -> torch.Tensor:
        return self.decoder.start(torch.as_tensor(latent, dtype=torch.float32, device=self.device))

    @torch.no_grad()
    def predict(self, depth: int, x: torch.Tensor, neighbors: np.ndarray, skip: torch.Tensor | None = None,
                skip_index: np.ndarray | None = None):
        nb = torch.as_tensor(neighbors.astype(np.int64), device=self.device)
        rows = None if skip_index is None else torch.as_tensor(skip_index.astype(np.int64), device=self.device)
        x, logits, plane = self.decoder.predict(depth, x, nb, skip, rows)
        return x, logits.cpu().numpy(), None if plane is None else plane.cpu().numpy()

    @torch.no_grad()
    def expand(self, depth: int, x: torch.Tensor, split: np.ndarray) -> torch.Tensor:
        return self.decoder.expand(depth, x, torch.as_tensor(split.astype(np.int64), device=self.device))
