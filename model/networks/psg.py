"""Point-set decoder (PointSetGen-style baseline): an MLP from the latent code to N points."""

from __future__ import annotations

import torch
from torch import nn


class PointSetDecoder(nn.Module):
    """Latent codes (B, L) -> points (B, N, 3) in the unit cube."""

    def __init__(self, latent: int = 128, points: int = 2048, hidden: tuple[int, ...] = (512, 1024)):
        super().__init__()
        layers, width = [], latent
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU(inplace=True)]
            width = h
        layers.append(nn.Linear(width, points * 3))
        self.mlp = nn.Sequential(*layers)
        self.points = points

    def forward(self, latent: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.mlp(latent)).reshape(len(latent), self.points, 3)


def chamfer_loss(pred: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """The paper's Chamfer distance (mean squared nearest distance both ways), batch mean.

    ``pred`` (B, N, 3), ``target`` (B, M, 3).
    """
    d = torch.cdist(pred, target).pow(2)
    return (d.min(dim=2).values.mean(dim=1) + d.min(dim=1).values.mean(dim=1)).mean()
