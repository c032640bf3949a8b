"""The foreground networks: which pixels of a photo show the object (background removal).

:class:`ForegroundNet` is a compact U-Net (Ronneberger et al. 2015): an encoder of ``levels``
stages, each two 3x3 convolutions with batch norm and ReLU, halving the resolution between stages
(stride-2 convolution); a decoder that upsamples (bilinear x2), concatenates the encoder's features
of the same resolution and applies two more convolutions; a 1x1 convolution to one logit per pixel.
Widths double per stage from ``width``, capped at 8 x ``width``.  :class:`LiteForegroundNet` is
the same design with its work moved to coarser resolutions.  Input: (B, 3, S, S) images normalised
as :func:`model.image.mask.mask_input` makes them (S divisible by the network's ``divisor``), or
with ``in_channels=4`` the refinement network's (B, 4, S, S) crops with the first mask
(:func:`model.image.mask.crop_input`); output: (B, 1, S, S) logits of "object".
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import torch
from torch import nn
from torch.nn import functional as F

from ..image.mask import MaskSpec, mask_input, mask_output


def _conv(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    """A 3x3 convolution (no bias), batch norm, ReLU."""
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, 1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


def _block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    """Two :func:`_conv` in one flat Sequential (the first with ``stride``)."""
    return nn.Sequential(*_conv(cin, cout, stride), *_conv(cout, cout))


def _decode(x: torch.Tensor, skips: list[torch.Tensor], up: nn.ModuleList) -> torch.Tensor:
    """A U-Net's decoder: from the coarsest features ``x``, for i from the last stage to 0,
    upsample x2 (bilinear), concatenate ``skips[i]`` and apply ``up[i]``."""
    for i in range(len(up) - 1, -1, -1):
        x = F.interpolate(x, scale_factor=2.0, mode="bilinear", align_corners=False)
        x = up[i](torch.cat([x, skips[i]], dim=1))
    return x


def _init(net: nn.Module, head: nn.Module) -> None:
    """He initialisation of every convolution but the head."""
    for m in net.modules():
        if isinstance(m, nn.Conv2d) and m is not head:
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu")


class ForegroundNet(nn.Module):
    """U-Net to object logits; see the module docstring."""

    divisor = 16

    def __init__(self, width: int = 8, levels: int = 5, in_channels: int = 3):
        super().__init__()
        if width < 1 or levels < 2:
            raise ValueError(f"the foreground network needs width >= 1 and levels >= 2, got {width}, {levels}")
        widths = [min(width * 2 ** i, width * 8) for i in range(levels)]
        self.levels = levels
        self.down = nn.ModuleList([_block(in_channels, widths[0])] +
                                  [_block(widths[i - 1], widths[i], 2) for i in range(1, levels)])
        self.up = nn.ModuleList([_block(widths[i + 1] + widths[i], widths[i]) for i in range(levels - 1)])
        self.head = nn.Conv2d(widths[0], 1, 1)
        _init(self, self.head)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        skips = []
        x = images
        for block in self.down:
            x = block(x)
            skips.append(x)
        return self.head(_decode(x, skips, self.up))


class LiteForegroundNet(nn.Module):
    """A U-Net whose work is mostly at coarse resolutions: at the input's resolution only two 3x3
    convolutions of ``width`` / 2 channels (the stem, and the decoder's last stage: a fifth of the
    multiply-adds), the first two-convolution stage at half the resolution (``width``), then stages
    doubling the channels up to 8 x ``width`` down to 1/32 of the input (a wider view of the scene
    than :class:`ForegroundNet`'s 1/16), and a decoder of one convolution per stage with half the
    encoder's channels (at most 4 x ``width``).  A fifth of :class:`ForegroundNet`'s multiply-adds
    at the same width; the same input and output."""

    divisor = 32

    def __init__(self, width: int = 16, in_channels: int = 3):
        super().__init__()
        if width < 2:
            raise ValueError(f"the light foreground network needs width >= 2, got {width}")
        enc = [width // 2, width, 2 * width, 4 * width, 8 * width, 8 * width]
        dec = [width // 2, width, 2 * width, 2 * width, 4 * width]
        self.stem = _conv(in_channels, enc[0])
        self.down = nn.ModuleList([nn.Sequential(_conv(enc[i - 1], enc[i], 2), _conv(enc[i], enc[i]))
                                   for i in range(1, len(enc))])
        ups = dec[1:] + enc[-1:]                    # what reaches decoder stage i from below
        self.up = nn.ModuleList([_conv(ups[i] + enc[i], dec[i]) for i in range(len(dec))])
        self.head = nn.Conv2d(dec[0], 1, 1)
        _init(self, self.head)

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        x = self.stem(images)
        skips = [x]
        for block in self.down:
            x = block(x)
            skips.append(x)
        return self.head(_decode(skips.pop(), skips, self.up))


FOREGROUND_ARCHS = {"unet": ForegroundNet, "unet-lite": LiteForegroundNet}
"""The foreground networks by name (``--arch``): each built from its ``width``."""


def mask_losses(logits: torch.Tensor, masks: torch.Tensor, skeletons: torch.Tensor | None = None,
                skeleton_weight: float = 0.0, thin: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
    """Binary cross-entropy plus soft Dice (``total``), and the batch's IoU at 0.5 (``iou``,
    reported, not trained): ``masks`` (B, 1, S, S) coverage in [0, 1].  With ``skeletons`` (B, 1,
    S, S) in {0, 1}, the masks' tubed skeletons (:func:`model.train.foreground.tubed_skeletons`),
    also the skeleton recall loss (Kirchhoff et al., ECCV 2024), ``1 -`` the share of each
    skeleton the soft mask covers, averaged over the images that have one (``skeleton``; added to
    ``total`` times ``skeleton_weight``): a leg or a wing's edge lost costs as much as the body's
    middle, whatever its area.  With ``thin`` (B, 1, S, S) in {0, 1}, the masks' thin parts
    (:func:`model.train.foreground.thin_parts`), also their recall at 0.5 (``thin_recall``,
    reported, over the batch's thin pixels)."""
    bce = F.binary_cross_entropy_with_logits(logits, masks)
    p = torch.sigmoid(logits)
    inter = (p * masks).sum(dim=(1, 2, 3))
    dice = 1 - (2 * inter + 1) / (p.sum(dim=(1, 2, 3)) + masks.sum(dim=(1, 2, 3)) + 1)
    with torch.no_grad():
        hard, truth = logits > 0, masks > 0.5
        iou = ((hard & truth).sum(dim=(1, 2, 3)).float() + 1e-6) / ((hard | truth).sum(dim=(1, 2, 3)).float() + 1e-6)
    out = {"total": bce + dice.mean(), "bce": bce, "dice": dice.mean(), "iou": iou.mean()}
    if thin is not None:
        with torch.no_grad():
            out["thin_recall"] = ((logits > 0).to(thin.dtype) * thin).sum() / thin.sum().clamp(min=1)
    if skeletons is not None:
        length = skeletons.sum(dim=(1, 2, 3))
        recall = (p * skeletons).sum(dim=(1, 2, 3)) / length.clamp(min=1)
        has = (length > 0).to(p.dtype)
        out["skeleton"] = ((1 - recall) * has).sum() / has.sum().clamp(min=1)
        out["total"] = out["total"] + skeleton_weight * out["skeleton"]
    return out


class ForegroundModel(nn.Module):
    """The training wrapper: ``forward(images, masks[, skeletons[, thin]])`` returns
    :func:`mask_losses` (the skeleton recall term weighted by ``skeleton_weight``)."""

    def __init__(self, width: int = 8, skeleton_weight: float = 0.0, arch: str = "unet", in_channels: int = 3):
        super().__init__()
        self.net = FOREGROUND_ARCHS[arch](width, in_channels=in_channels)
        self.skeleton_weight = skeleton_weight

    def forward(self, images: torch.Tensor, masks: torch.Tensor, skeletons: torch.Tensor | None = None,
                thin: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        return mask_losses(self.net(images), masks, skeletons, self.skeleton_weight, thin)


def torch_segment(net: nn.Module, spec: MaskSpec) -> Callable[[np.ndarray], np.ndarray]:
    """A foreground network in torch, as :meth:`export.runtime.Runtime.segment` runs its graph: an
    (H, W, 3) uint8 image to its object probability on the network's grid."""

    def segment(rgb: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return mask_output(net(torch.from_numpy(mask_input(rgb, spec)[None])).numpy()[0, 0])
    return segment
