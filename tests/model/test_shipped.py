"""The shipped checkpoints under models/checkpoints load, match their provenance, and run."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from model.files import sha256_file
from model.checkpoint import load_model

CHECKPOINTS = Path(__file__).resolve().parents[2] / "models" / "checkpoints"
BUNDLES = CHECKPOINTS.parent / "bundles"
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
    loaded = load_model(folder)             # checks the weights' sha256 again; needs no teacher run
    model, cfg = loaded.model, loaded.config
    assert sum(p.numel() for p in model.parameters()) <= meta["parameters"]
    # a white square on a grey photo: the model gives a finite latent and a non-empty octree
    x = torch.from_numpy(prepare_image(_photo(), ImageSpec(size=cfg.image_size))[None])
    with torch.no_grad():
        latent = model.encoder(x)
    assert torch.isfinite(latent).all()
    tree = split_octree(decode(TorchSteps(model.decoder), latent.numpy()))[0]
    assert sum(tree.leaves_per_depth()) > 0
    assert meta["evaluation"]["chamfer_x1e3_category_mean"] > 0


def _photo() -> np.ndarray:
    """A white square on a grey photo."""
    img = np.full((90, 120, 3), 128, np.uint8)
    img[20:70, 30:90] = 240
    return img


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_bundle_is_the_checkpoint_s_export_and_matches_it(name):
    """The committed bundle verifies, records its checkpoint's weights, and onnxruntime gives
    torch's latent (1e-4) and octree on a photo."""
    from export.bundle import load_bundle
    from export.runtime import Runtime
    from model.decode import decode
    from model.networks import TorchSteps
    from model.preprocess import prepare_image

    bundle = load_bundle(BUNDLES / name)
    meta = json.loads((CHECKPOINTS / name / "model.json").read_text())
    assert bundle.meta["provenance"]["weights_sha256"] == meta["weights_sha256"]
    assert bundle.meta["evaluation"] == meta["evaluation"]
    model = load_model(CHECKPOINTS / name).model
    x = prepare_image(_photo(), bundle.image_spec())[None]
    runtime = Runtime(bundle, threads=1)
    latent = runtime.encode_image(x)
    with torch.no_grad():
        assert np.abs(latent - model.encoder(torch.from_numpy(x)).numpy()).max() <= 1e-4
    a, b = runtime.decode(latent), decode(TorchSteps(model.decoder), latent)
    for la, lb in zip(a.levels, b.levels):
        assert np.array_equal(la.key, lb.key) and np.array_equal(la.label, lb.label)
        assert np.abs(la.plane - lb.plane).max(initial=0) <= 1e-4


def test_models_folder_fits_its_budget():
    total = sum(f.stat().st_size for f in CHECKPOINTS.parent.rglob("*") if f.is_file())
    assert total <= 60 * 1024 * 1024
