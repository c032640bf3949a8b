"""Networks on real (tiny) octrees: shapes, gradients, overfitting, decoding."""

import numpy as np
import pytest
import torch

from model.decode import decode
from model.networks import ARCHS, Autoencoder, TorchSteps
from model.nn.tensors import OctreeTensors
from model.octree.batch import split_octree
from model.train.data import RecordSet


@pytest.mark.parametrize("arch", sorted(ARCHS))
def test_every_arch_gives_finite_losses_and_gradients_to_every_parameter(tiny_data, arch):
    torch.manual_seed(0)
    data = RecordSet(tiny_data, "train", ARCHS[arch].octree, depth=5, points=256)
    octree, points = data.batch(np.arange(4))
    model = Autoencoder(arch, 5, latent=32, base_channels=4, top_channels=16, psg_points=256)
    losses = model(OctreeTensors.from_octree(octree), torch.from_numpy(points))
    assert torch.isfinite(losses["total"]) and float(losses["total"].detach()) > 0
    losses["total"].backward()
    missing = [n for n, p in model.named_parameters() if p.grad is None or not torch.isfinite(p.grad).all()]
    assert missing == []
    latent = model.encoder(OctreeTensors.from_octree(octree))
    assert latent.shape == (4, 32) and not torch.allclose(latent[0], latent[1])


def test_adaptive_decoder_overfits_two_shapes_and_decodes_their_structure(tiny_data):
    torch.manual_seed(0)
    data = RecordSet(tiny_data, "train", "adaptive", depth=5, points=256)
    octree, points = data.batch(np.arange(2))
    tensors = OctreeTensors.from_octree(octree)
    model = Autoencoder("aocnn", 5, latent=32, base_channels=8, top_channels=32)
    opt = torch.optim.Adam(model.parameters(), lr=5e-3)
    first = None
    for step in range(80):
        loss = model(tensors)["total"]
        first = float(loss.detach()) if first is None else first
        opt.zero_grad()
        loss.backward()
        opt.step()
    assert float(loss.detach()) < 0.25 * first
    model.eval()
    with torch.no_grad():
        latent = model.encoder(tensors).numpy()
    decoded = split_octree(decode(TorchSteps(model.decoder), latent))
    truth = split_octree(octree)
    for got, want in zip(decoded, truth):
        # After overfitting, the predicted statuses reproduce most of the true structure.
        g, w = got.levels[4], want.levels[4]
        common = np.intersect1d(g.key, w.key)
        assert len(common) > 0.9 * len(w.key)
        gl = g.label[np.searchsorted(g.key, common)]
        wl = w.label[np.searchsorted(w.key, common)]
        assert np.mean(gl == wl) > 0.9
        assert sum(got.leaves_per_depth()) > 0.5 * sum(want.leaves_per_depth())


def test_chamfer_loss_matches_the_dense_formula_in_value_and_gradient():
    from model.networks import chamfer_loss

    torch.manual_seed(1)
    pred = torch.rand(2, 50, 3, dtype=torch.float64, requires_grad=True)
    target = torch.rand(2, 70, 3, dtype=torch.float64)
    d = torch.cdist(pred, target).pow(2)
    dense = (d.min(2).values.mean(1) + d.min(1).values.mean(1)).mean()
    g_dense, = torch.autograd.grad(dense, pred)
    fast = chamfer_loss(pred, target)
    g_fast, = torch.autograd.grad(fast, pred)
    assert torch.allclose(fast, dense) and torch.allclose(g_fast, g_dense)
