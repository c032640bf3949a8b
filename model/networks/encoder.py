"""Octree encoders: Adaptive O-CNN (plane signal at every depth, fused by max) and O-CNN.

Paper section 4.1: per depth a conv block, features pooled to the parent depth and fused with
that depth's own branch (the 4-channel plane signal (n, d*) through a conv) by element-wise max,
down to the full depth 2, then fully connected layers to the latent code.  O-CNN's encoder is
the same network reading the signal at the finest depth only.
"""

from __future__ import annotations

import torch
from torch import nn

from ..nn.ops import ConvBnRelu, octree_max_pool
from ..nn.tensors import OctreeTensors

SIGNAL_CHANNELS = 4


def default_channels(depth: int, base: int = 8, top: int = 64, full_depth: int = 2) -> dict[int, int]:
    """Channels per depth: ``base`` at the max depth, doubling towards the root, capped at ``top``."""
    return {d: min(top, base << (depth - d)) for d in range(full_depth, depth + 1)}


class OctreeEncoder(nn.Module):
    """Octree (B shapes) -> latent codes (B, latent).  ``signal='all'`` is Adaptive O-CNN's
    encoder, ``signal='finest'`` O-CNN's."""

    def __init__(self, depth: int, channels: dict[int, int] | None = None, latent: int = 128,
                 signal: str = "all", full_depth: int = 2):
        super().__init__()
        if signal not in ("all", "finest"):
            raise ValueError("signal must be 'all' or 'finest'")
        self.depth, self.full_depth, self.signal = depth, full_depth, signal
        self.channels = channels or default_channels(depth, full_depth=full_depth)
        ch = self.channels
        branch_depths = range(full_depth, depth + 1) if signal == "all" else [depth]
        self.branch = nn.ModuleDict({str(d): ConvBnRelu(SIGNAL_CHANNELS, ch[d]) for d in branch_depths})
        self.down = nn.ModuleDict({str(d): ConvBnRelu(ch[d], ch[d - 1]) for d in range(depth, full_depth, -1)})
        width = 64 * ch[full_depth]
        self.head = nn.Sequential(nn.Linear(width, 256), nn.BatchNorm1d(256), nn.ReLU(inplace=True),
                                  nn.Linear(256, latent), nn.Tanh())

    def forward(self, octree: OctreeTensors) -> torch.Tensor:
        lv = octree.levels
        return self.encode([v.plane for v in lv], [v.neighbors for v in lv], [v.split for v in lv])

    def encode(self, signals: list, neighbors: list, splits: list) -> torch.Tensor:
        """The network on plain per-depth tables (lists indexed by depth; the graph export's entry):
        ``signals[d]`` (N_d, 4) planes, ``neighbors[d]`` (N_d, 27), ``splits[d]`` split indices."""
        return self.encode_features(signals, neighbors, splits)[0]

    def features(self, octree: OctreeTensors) -> tuple[torch.Tensor, dict[int, torch.Tensor]]:
        """Latent codes and the features of every depth's octants (see :meth:`encode_features`)."""
        lv = octree.levels
        return self.encode_features([v.plane for v in lv], [v.neighbors for v in lv], [v.split for v in lv])

    def encode_features(self, signals: list, neighbors: list, splits: list
                        ) -> tuple[torch.Tensor, dict[int, torch.Tensor]]:
        """:meth:`encode`, also returning the features (N_d, channels[d]) of the input's octants
        at each depth d (full depth .. depth) as the depth's convolution reads them: what the
        output-guided skip connections of a decoder add to the octants they share."""
        d = self.depth
        x = self.branch[str(d)](signals[d], neighbors[d])
        per_depth = {}
        for d in range(self.depth, self.full_depth, -1):
            per_depth[d] = x
            x = self.down[str(d)](x, neighbors[d])
            x = octree_max_pool(x, splits[d - 1], neighbors[d - 1].shape[0])
            if self.signal == "all":
                x = torch.maximum(x, self.branch[str(d - 1)](signals[d - 1], neighbors[d - 1]))
        per_depth[self.full_depth] = x
        # Depth 2 is full: 64 octants per shape, shape-major in key order.
        return self.head(x.reshape(-1, 64 * x.shape[1])), per_depth
