"""Batch normalisation folded into the layer before it, for inference graphs without BN nodes.

In eval mode BN is the affine map ``y = s * x + t`` per channel (``s = gamma / sqrt(var + eps)``,
``t = beta - s * mean``); it folds into the preceding linear layer's output channels.  Every BN
of this project's networks directly follows its linear layer (OctreeConv, OctreeDeconv, Linear,
Conv2d) as the previous sibling module; :func:`fold_batchnorm` relies on that and refuses a
network where a BN is left over.
"""

from __future__ import annotations

import copy

import torch
from torch import nn

from model.nn.ops import OctreeConv, OctreeDeconv

_FOLDABLE = (nn.Linear, nn.Conv2d, OctreeConv, OctreeDeconv)


def _affine(bn: nn.modules.batchnorm._BatchNorm) -> tuple[torch.Tensor, torch.Tensor]:
    scale = bn.weight / torch.sqrt(bn.running_var + bn.eps) if bn.affine else 1 / torch.sqrt(bn.running_var + bn.eps)
    shift = (bn.bias if bn.affine else 0) - scale * bn.running_mean
    return scale, shift


def _fold_into(layer: nn.Module, bn: nn.modules.batchnorm._BatchNorm) -> None:
    scale, shift = _affine(bn)
    w = layer.weight
    if isinstance(layer, (OctreeConv, OctreeDeconv)):        # (K, Cin, Cout): output channels last
        w.mul_(scale)
    else:                                                    # Linear (out, in), Conv2d (out, in, kh, kw)
        w.mul_(scale.reshape(-1, *([1] * (w.dim() - 1))))
    bias = shift if layer.bias is None else layer.bias * scale + shift
    if layer.bias is None:
        layer.bias = nn.Parameter(bias.clone())
    else:
        layer.bias.copy_(bias)


@torch.no_grad()
def fold_batchnorm(model: nn.Module) -> nn.Module:
    """An eval-mode copy of ``model`` with every BatchNorm folded into its preceding layer and
    replaced by Identity; the outputs equal the original's in eval mode (up to rounding)."""
    model = copy.deepcopy(model).eval()
    for parent in model.modules():
        previous = None
        for name, child in list(parent.named_children()):
            if isinstance(child, nn.modules.batchnorm._BatchNorm) and isinstance(previous, _FOLDABLE):
                out = previous.weight.shape[-1] if isinstance(previous, (OctreeConv, OctreeDeconv)) \
                    else previous.weight.shape[0]
                if out == child.num_features:
                    _fold_into(previous, child)
                    setattr(parent, name, nn.Identity())
                    child = None
            previous = child
    left = [name for name, m in model.named_modules() if isinstance(m, nn.modules.batchnorm._BatchNorm)]
    if left:
        raise ValueError(f"batch norm not preceded by a foldable layer: {', '.join(left)}")
    return model
