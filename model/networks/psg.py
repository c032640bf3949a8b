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

    ``pred`` (B, N, 3), ``target`` (B, M, 3).  Nearest neighbours are found without gradient
    (the assignment is piecewise constant) and only the matched pairs are differentiated: the
    same value and gradient as differentiating the min over all pairs, without a (B, N, M)
    backward pass.
    """
    with torch.no_grad():
        d = torch.cdist(pred, target)
        to_target, to_pred = d.argmin(dim=2), d.argmin(dim=1)
    near_t = target.gather(1, to_target.unsqueeze(-1).expand(-1, -1, 3))
    near_p = pred.gather(1, to_pred.unsqueeze(-1).expand(-1, -1, 3))
    forward = ((pred - near_t) ** 2).sum(-1).mean(1)
    backward = ((target - near_p) ** 2).sum(-1).mean(1)
    return (forward + backward).mean()
