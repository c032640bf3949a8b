"""Small randomly initialised models of every exportable architecture, saved as checkpoint folders
and exported once per test session; real octrees (test meshes, procedural shapes) to run them on."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
import torch
import trimesh

from export.parity import probe_octrees
from model.data.shapes import generate
from model.decode import decode
from model.networks import TorchSteps
from model.octree import build_octree
from model.octree.batch import merge_octrees
from model.train.loop import TrainConfig, build_model

from ..octree.conftest import mesh_path, mesh_points

DEPTH = 5
CONFIGS = {
    # name: TrainConfig overrides (depth 5 for the product's decoder; the baselines at depth 4)
    "aocnn": dict(arch="aocnn", depth=DEPTH, structure_loss="balanced", pred_hidden=16),
    "ocnn-patch-star": dict(arch="ocnn-patch-star", depth=4),
    "ocnn-patch": dict(arch="ocnn-patch", depth=4),
    "ocnn-binary": dict(arch="ocnn-binary", depth=4),
    "image-resnet18": dict(task="image", arch="aocnn", depth=DEPTH, encoder="resnet18", encoder_width=8,
                           image_size=64, pred_hidden=16),
    "completion-aocnn": dict(task="completion", arch="aocnn", depth=DEPTH, structure_loss="balanced", pred_hidden=16),
    "completion-guided": dict(task="completion", arch="aocnn", depth=DEPTH, structure_loss="balanced", pred_hidden=16,
                              skips=True),
    "classify-aocnn": dict(task="classify", arch="aocnn", depth=DEPTH, categories=["chair", "airplane", "car"]),
}


def make_model(name: str) -> tuple[torch.nn.Module, TrainConfig]:
    """A model with random weights and non-trivial batch-norm statistics (as a trained one has)."""
    cfg = TrainConfig(data="", out="", latent=32, channels=4, **CONFIGS[name])
    torch.manual_seed(0)
    model = build_model(cfg)
    g = torch.Generator().manual_seed(1)
    with torch.no_grad():
        for m in model.modules():
            if isinstance(m, torch.nn.modules.batchnorm._BatchNorm):
                n = m.num_features
                m.running_mean.copy_(torch.rand(n, generator=g) - 0.5)
                m.running_var.copy_(0.5 + torch.rand(n, generator=g))
                m.weight.copy_(0.5 + torch.rand(n, generator=g))
                m.bias.copy_(0.2 * torch.rand(n, generator=g) - 0.1)
    model.eval()
    if hasattr(model, "decoder"):
        latent, guide = np.random.default_rng(0).uniform(-0.2, 0.2, (2, cfg.latent)), None
        if cfg.skips:                  # a guided decoder reads real input octrees
            with torch.no_grad():
                latent, guide = model.encode_octree(probe_octrees(cfg.depth, batch=2))
            latent = latent.numpy()
        decode(_BiasToMixedTree(model.decoder), latent, guide=guide)
    return model, cfg


class _BiasToMixedTree(TorchSteps):
    """Sets each depth's status biases, while decoding, so that about 40% of the octants are empty
    and the rest split between split and leaf: a random decoder otherwise empties everything."""

    @torch.no_grad()
    def predict(self, depth, x, neighbors, *skip):
        logits = super().predict(depth, x, neighbors, *skip)[1]
        bias = self.decoder.pred[str(depth)][-1].bias
        if logits.shape[1] == 3:
            bias[1] -= float(np.median(logits[:, 1] - logits[:, 2]))
            logits = super().predict(depth, x, neighbors, *skip)[1]
        bias[0] += float(np.quantile(logits[:, 1:].max(1) - logits[:, 0], 0.4))
        return super().predict(depth, x, neighbors, *skip)


def save_checkpoint(model: torch.nn.Module, cfg: TrainConfig, folder) -> None:
    """A checkpoint folder as research.release writes it (model.pt + model.json)."""
    folder.mkdir(parents=True, exist_ok=True)
    torch.save(model.state_dict(), folder / "model.pt")
    config = {k: v for k, v in dataclasses.asdict(cfg).items() if k not in ("data", "out", "progress")}
    (folder / "model.json").write_text(json.dumps({"format": 1, "config": config, "steps": 0}))


@pytest.fixture(scope="session")
def exported(tmp_path_factory):
    """name -> (model, cfg, bundle folder), exported on first use."""
    from export.exporter import export

    cache = {}

    def get(name: str):
        if name not in cache:
            model, cfg = make_model(name)
            root = tmp_path_factory.mktemp(name)
            save_checkpoint(model, cfg, root / "checkpoint")
            export(root / "checkpoint", root / "bundle")
            cache[name] = (model, cfg, root / "bundle")
        return cache[name]

    return get


def _shape_clouds(n: int = 30_000) -> list[tuple[np.ndarray, np.ndarray]]:
    """Real inputs of different kinds: a sculpted shape, a CAD part and three generated categories."""
    clouds = [mesh_points(trimesh.load(mesh_path(name), force="mesh"), n) for name in ("blob.obj", "cad_block.stl")]
    for category, index in (("chair", 0), ("airplane", 1), ("car", 2)):
        clouds.append(mesh_points(generate(category, index), n))
    return clouds


@pytest.fixture(scope="session")
def clouds():
    return _shape_clouds()


def octree_batch(clouds, depth: int, adaptive: bool, batch: int = 3, start: int = 0):
    """A batch of ``batch`` real octrees (consecutive clouds, wrapping around)."""
    picked = [clouds[(start + i) % len(clouds)] for i in range(batch)]
    return merge_octrees([build_octree(c, depth, adaptive=adaptive) for c in picked])
