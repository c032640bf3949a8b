"""The shipped checkpoints under models/checkpoints load, match their provenance, and run."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from model.files import sha256_file
from model.train.loop import build_model, config_from_dict

CHECKPOINTS = Path(__file__).resolve().parents[2] / "models" / "checkpoints"
SHIPPED = ["image-to-shape"]


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_checkpoint_matches_its_json_and_decodes(name):
    from model.decode import decode
    from model.networks import TorchSteps
    from model.octree.batch import split_octree
    from model.preprocess import ImageSpec, prepare_image

    folder = CHECKPOINTS / name
    meta = json.loads((folder / "model.json").read_text())
    weights = folder / meta["weights"]
    assert sha256_file(weights) == meta["weights_sha256"]
    for key in ("command", "train_command", "data", "evaluation", "config"):
        assert meta[key]
    assert len(meta["data"]["manifest_sha256"]) == 64
    cfg = config_from_dict({**meta["config"], "data": "", "out": ""})
    model = build_model(cfg)
    model.load_state_dict(torch.load(weights, map_location="cpu", weights_only=True), strict=True)
    model.eval()
    assert sum(p.numel() for p in model.parameters()) <= meta["parameters"]
    # a white square on a grey photo: the model gives a finite latent and a non-empty octree
    img = np.full((90, 120, 3), 128, np.uint8)
    img[20:70, 30:90] = 240
    x = torch.from_numpy(prepare_image(img, ImageSpec(size=cfg.image_size))[None])
    with torch.no_grad():
        latent = model.encoder(x)
    assert torch.isfinite(latent).all()
    tree = split_octree(decode(TorchSteps(model.decoder), latent.numpy()))[0]
    assert sum(tree.leaves_per_depth()) > 0
    assert meta["evaluation"]["chamfer_x1e3_category_mean"] > 0


def test_models_folder_fits_its_budget():
    total = sum(f.stat().st_size for f in CHECKPOINTS.parent.rglob("*") if f.is_file())
    assert total <= 60 * 1024 * 1024
