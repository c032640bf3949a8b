"""Batch-norm folding is exact for each kind of foldable layer, eps included: with running
variances as small as eps itself, leaving eps out changes the outputs by tens of percent."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from export.fold import fold_batchnorm


def _with_statistics(model: nn.Module, seed: int) -> nn.Module:
    g = torch.Generator().manual_seed(seed)
    for m in model.modules():
        if isinstance(m, nn.modules.batchnorm._BatchNorm):
            n = m.num_features
            m.running_mean.copy_(torch.randn(n, generator=g))
            m.running_var.copy_(m.eps * (0.5 + torch.rand(n, generator=g)))    # comparable to eps
            m.weight.data.copy_(torch.randn(n, generator=g))
            m.bias.data.copy_(torch.randn(n, generator=g))
    return model.eval()


@pytest.mark.parametrize("make,shape", [
    (lambda: nn.Sequential(nn.Linear(16, 8), nn.BatchNorm1d(8), nn.ReLU()), (32, 16)),
    (lambda: nn.Sequential(nn.Conv2d(3, 6, 3, bias=False), nn.BatchNorm2d(6)), (4, 3, 10, 10)),
])
def test_folded_layers_give_the_same_outputs(make, shape):
    torch.manual_seed(0)
    model = _with_statistics(make(), 1)
    x = torch.randn(*shape, dtype=torch.float64)
    model = model.double()
    folded = fold_batchnorm(model)
    assert not any(isinstance(m, nn.modules.batchnorm._BatchNorm) for m in folded.modules())
    with torch.no_grad():
        want, got = model(x), folded(x)
    assert torch.allclose(got, want, rtol=1e-9, atol=1e-9 * float(want.abs().max()))
