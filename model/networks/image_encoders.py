"""Image encoders of paper section 5.3, written here (torchvision cannot be installed beside torch).

``resnet18``: the ResNet-18 layout (He et al. 2016) that AtlasNet and the paper use, with the
stage widths as a parameter (``width`` x (1, 2, 4, 8)); ``lenet``: the LeNet-style encoder of
OctGen's comparison.  Both map (B, 3, S, S) images to latent codes (B, L) in (-1, 1) (a tanh, as
the octree encoder's), so an image encoder can stand in for an autoencoder's octree encoder.
"""

from __future__ import annotations

import torch
from torch import nn

IMAGE_ENCODERS = ("resnet18", "lenet")


class BasicBlock(nn.Module):
    """Two 3x3 conv + BN, identity (or 1x1 strided projection) shortcut, ReLU."""

    def __init__(self, cin: int, cout: int, stride: int = 1):
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.bn1 = nn.BatchNorm2d(cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.bn2 = nn.BatchNorm2d(cout)
        self.relu = nn.ReLU(inplace=True)
        self.short = (nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.BatchNorm2d(cout))
                      if stride != 1 or cin != cout else nn.Identity())

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.relu(self.bn1(self.conv1(x)))
        return self.relu(self.bn2(self.conv2(y)) + self.short(x))


class ResNet18(nn.Module):
    """ResNet-18: 7x7/2 stem, 3x3/2 max pool, 4 stages of 2 basic blocks, global average pool, FC."""

    def __init__(self, latent: int = 128, width: int = 32):
        super().__init__()
        w = [width, 2 * width, 4 * width, 8 * width]
        self.stem = nn.Sequential(nn.Conv2d(3, w[0], 7, 2, 3, bias=False), nn.BatchNorm2d(w[0]),
                                  nn.ReLU(inplace=True), nn.MaxPool2d(3, 2, 1))
        blocks, cin = [], w[0]
        for i, c in enumerate(w):
            blocks += [BasicBlock(cin, c, 1 if i == 0 else 2), BasicBlock(c, c)]
            cin = c
        self.blocks = nn.Sequential(*blocks)
        self.head = nn.Sequential(nn.AdaptiveAvgPool2d(1), nn.Flatten(), nn.Linear(cin, latent), nn.Tanh())
        for m in self.modules():
            if isinstance(m, nn.Conv2d):
                nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.head(self.blocks(self.stem(images)))


class LeNet(nn.Module):
    """LeNet layout: conv5-pool-conv5-pool (20, 50 channels), FC 500, FC latent."""

    def __init__(self, latent: int = 128, width: int = 20):
        super().__init__()
        self.features = nn.Sequential(
            nn.Conv2d(3, width, 5), nn.ReLU(inplace=True), nn.MaxPool2d(2),
            nn.Conv2d(width, 50 * width // 20, 5), nn.ReLU(inplace=True), nn.MaxPool2d(2),
            nn.AdaptiveAvgPool2d(6))
        self.head = nn.Sequential(nn.Flatten(), nn.Linear(50 * width // 20 * 36, 500), nn.ReLU(inplace=True),
                                  nn.Linear(500, latent), nn.Tanh())

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.head(self.features(images))


def image_encoder(name: str, latent: int = 128, width: int | None = None) -> nn.Module:
    """An encoder of :data:`IMAGE_ENCODERS`; ``width`` None takes its default."""
    if name == "resnet18":
        return ResNet18(latent, width or 32)
    if name == "lenet":
        return LeNet(latent, width or 20)
    raise ValueError(f"unknown image encoder {name!r}; choose from {', '.join(IMAGE_ENCODERS)}")
