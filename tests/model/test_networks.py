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


def test_structure_losses_balanced_is_the_mean_of_class_means_and_focal_down_weights_easy_octants():
    from torch.nn import functional as F

    from model.networks.decoder import structure_loss

    torch.manual_seed(0)
    logits = torch.randn(50, 3)
    target = torch.tensor([0] * 40 + [1] * 3 + [2] * 7)
    per = F.cross_entropy(logits, target, reduction="none")
    class_means = [per[target == c].mean() for c in range(3)]
    assert torch.allclose(structure_loss(logits, target, "balanced"), torch.stack(class_means).mean())
    assert torch.allclose(structure_loss(logits, target, "ce"), per.mean())
    # a class absent from the batch does not count
    two = target.clamp(max=1)
    per2 = F.cross_entropy(logits, two, reduction="none")
    assert torch.allclose(structure_loss(logits, two, "balanced"),
                          (per2[two == 0].mean() + per2[two == 1].mean()) / 2)
    p_true = F.softmax(logits, 1)[torch.arange(50), target]
    assert torch.allclose(structure_loss(logits, target, "focal"), ((1 - p_true) ** 2 * per).mean())
    with pytest.raises(ValueError, match="structure loss"):
        structure_loss(logits, target, "hinge")


def test_the_minority_split_class_survives_where_cross_entropy_lets_it_die():
    """A prediction module that cannot separate a rare class well: cross-entropy hardly ever
    predicts it, the class-balanced loss does (the decoder's depth-5 collapse in miniature).
    Focal loss (gamma 2, no class weights) does not help here: it keeps the CE boundary."""
    loss = "balanced"
    g = torch.Generator().manual_seed(0)
    n = 4000
    target = (torch.rand(n, generator=g) < 0.1).long()          # 10% minority
    x = torch.randn(n, 4, generator=g) + 0.5 * target[:, None]   # overlapping classes
    recalls = {}
    for kind in ("ce", loss):
        torch.manual_seed(0)
        head = torch.nn.Linear(4, 2)
        opt = torch.optim.Adam(head.parameters(), lr=0.05)
        from model.networks.decoder import structure_loss
        for _ in range(200):
            opt.zero_grad()
            structure_loss(head(x), target, kind).backward()
            opt.step()
        pred = head(x).argmax(1)
        recalls[kind] = float((pred[target == 1] == 1).float().mean())
    assert recalls["ce"] < 0.15 and recalls[loss] > 0.5


@pytest.mark.parametrize("encoder", ["resnet18", "lenet"])
def test_image_encoders_give_bounded_latents_and_gradients(encoder):
    from model.networks import image_encoder

    torch.manual_seed(0)
    net = image_encoder(encoder, latent=16, width=4)
    z = net(torch.randn(3, 3, 64, 64))
    assert z.shape == (3, 16) and float(z.detach().abs().max()) < 1 and not torch.allclose(z[0], z[1])
    z.sum().backward()
    assert all(p.grad is not None and torch.isfinite(p.grad).all() for p in net.parameters())
    with pytest.raises(ValueError, match="unknown image encoder"):
        image_encoder("vgg")


def test_atlasnet_decoder_patches_are_per_shape_and_cover_the_grid():
    from model.networks import AtlasNetDecoder

    torch.manual_seed(0)
    dec = AtlasNetDecoder(latent=8, patches=4, train_points=40)
    z = torch.randn(3, 8)
    assert dec(z).shape == (3, 40, 3)
    grid = dec.grid(z, side=5).detach()
    assert grid.shape == (3, 100, 3) and float(grid.min()) >= 0 and float(grid.max()) <= 1
    assert torch.allclose(grid[2], dec.grid(z[2:], side=5)[0], atol=1e-6)    # shapes do not mix
    faces = dec.triangles(side=5)
    assert faces.shape == (4 * 2 * 16, 3) and int(faces.max()) == 99
