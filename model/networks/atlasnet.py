"""AtlasNet-style decoder (Groueix et al. 2018), the paper's second comparison row in section 5.3.

K square patches, each an MLP from (latent code, uv in [0, 1]^2) to a point in the unit cube;
trained with the Chamfer distance on random uv samples, evaluated on a regular uv grid.  The K
MLPs run as one batched matmul per layer (weights (K, in, out)).
"""

from __future__ import annotations

import math

import torch
from torch import nn


class AtlasNetDecoder(nn.Module):
    """Latent codes (B, L) -> points (B, K * P, 3) on K deformed unit squares."""

    def __init__(self, latent: int = 128, patches: int = 25, hidden: tuple[int, ...] = (128, 128, 64),
                 train_points: int = 2000):
        super().__init__()
        self.patches, self.train_points = patches, train_points
        dims = [latent + 2, *hidden, 3]
        self.weights = nn.ParameterList()
        self.biases = nn.ParameterList()
        for cin, cout in zip(dims[:-1], dims[1:]):
            bound = 1 / math.sqrt(cin)
            self.weights.append(nn.Parameter(torch.empty(patches, cin, cout).uniform_(-bound, bound)))
            self.biases.append(nn.Parameter(torch.empty(patches, 1, cout).uniform_(-bound, bound)))

    def surface(self, latent: torch.Tensor, uv: torch.Tensor) -> torch.Tensor:
        """Points (B, K * P, 3) of uv samples (K, P, 2), patch-major."""
        b, k, p = len(latent), self.patches, uv.shape[1]
        code = latent[None, :, None, :].expand(k, b, p, latent.shape[1])
        x = torch.cat([code, uv[:, None].expand(k, b, p, 2)], dim=3).reshape(k, b * p, -1)
        for i, (w, bias) in enumerate(zip(self.weights, self.biases)):
            x = torch.baddbmm(bias, x, w)
            x = torch.relu(x) if i < len(self.weights) - 1 else 0.5 + 0.5 * torch.tanh(x)
        return x.reshape(k, b, p, 3).transpose(0, 1).reshape(b, k * p, 3)

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        """Training output: ``train_points`` / K random uv samples per patch."""
        per = max(1, self.train_points // self.patches)
        uv = torch.rand(self.patches, per, 2, device=latent.device)
        return self.surface(latent, uv)

    def grid(self, latent: torch.Tensor, side: int = 20) -> torch.Tensor:
        """Evaluation output: a ``side`` x ``side`` regular uv grid per patch."""
        t = (torch.arange(side, dtype=latent.dtype, device=latent.device) + 0.5) / side
        uv = torch.stack(torch.meshgrid(t, t, indexing="ij"), -1).reshape(1, -1, 2)
        return self.surface(latent, uv.expand(self.patches, -1, 2))

    def triangles(self, side: int = 20) -> torch.Tensor:
        """Faces (K * 2 (side-1)^2, 3) of :meth:`grid`'s points, for a mesh of the patches."""
        i = torch.arange(side - 1)
        a = (i[:, None] * side + i[None, :]).reshape(-1)
        quad = torch.stack([a, a + side, a + 1, a + 1, a + side, a + side + 1], 1).reshape(-1, 3)
        offset = torch.arange(self.patches)[:, None, None] * side * side
        return (quad[None] + offset).reshape(-1, 3)
