"""Split calibration: the bias matches predicted and true split counts and lives in the weights."""

import json

import numpy as np
import torch

from model.checkpoint import load_model
from model.octree import SPLIT
from model.train.loop import TrainConfig, Trainer
from model.train.tasks import TASKS
from research.calibrate import calibrate, matching_bias, split_logits


def test_matching_bias_equalises_counts():
    rng = np.random.default_rng(0)
    labels = rng.choice(3, size=5000, p=[0.5, 0.1, 0.4])
    logits = rng.normal(size=(5000, 3))
    logits[:, SPLIT] += 0.8                      # over-predicts split, like a balanced loss
    b, row = matching_bias(logits, labels)
    assert b < 0 and abs(row["predicted_over_true"] - 1) < 0.05
    z = logits.copy()
    z[:, SPLIT] += b
    assert abs((z.argmax(1) == SPLIT).sum() / (labels == SPLIT).sum() - row["predicted_over_true"]) < 1e-3


def test_calibrated_copy_differs_only_in_split_biases_and_matches_counts(tiny_data, tmp_path):
    cfg = TrainConfig(data=str(tiny_data), depth=5, arch="aocnn", out=str(tmp_path / "run"), iters=30,
                      batch_size=4, latent=32, channels=4, progress=False, structure_loss="balanced",
                      pred_hidden=16)
    Trainer(cfg).run()
    before = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)["model"]
    report = calibrate(str(tmp_path / "run"), str(tiny_data), str(tmp_path / "cal"), split="train")
    after = torch.load(tmp_path / "cal" / "checkpoint.pt", weights_only=False)["model"]
    changed = sorted(k for k in before if not torch.equal(before[k], after[k]))
    assert set(changed) <= {f"decoder.pred.{d}.3.bias" for d in report["depths"]}
    for d, row in report["depths"].items():
        diff = after[f"decoder.pred.{d}.3.bias"] - before[f"decoder.pred.{d}.3.bias"]
        assert torch.allclose(diff[:3], torch.tensor([0.0, row["bias"], 0.0]), atol=1e-6)
        assert torch.equal(diff[3:], torch.zeros_like(diff[3:]))          # plane outputs untouched
    assert json.loads((tmp_path / "cal" / "calibration.json").read_text()) == report
    # re-measured on the calibrated model: the counts are matched as reported
    loaded = load_model(tmp_path / "cal")
    model, cfg2 = loaded.model, loaded.config
    cfg2.data = str(tiny_data)
    for d, (logits, labels) in split_logits(model, cfg2, TASKS["autoencoder"].dataset(cfg2, "train", 0)).items():
        ratio = (logits.argmax(1) == SPLIT).sum() / max(1, (labels == SPLIT).sum())
        assert abs(ratio - report["depths"][str(d)]["predicted_over_true"]) < 1e-3   # reported to 4 decimals


def test_keep_scan_takes_the_least_missing_part_among_settings_tied_on_chamfer():
    from research.calibrate import choose_keep_scan

    rng = np.random.default_rng(0)
    shapes = [(c, f"{c}{i}") for c in ("chair", "lamp") for i in range(30)]
    base = rng.uniform(0.2, 0.4, len(shapes))

    def rows(chamfer_shift, missing):
        return [{"category": c, "shape_id": s, "chamfer_x1e3": b + chamfer_shift + rng.normal(0, 0.05),
                 "missing_x1e3": missing} for (c, s), b in zip(shapes, base)]

    lowest = rows(0.0, 0.50)              # the lowest Chamfer, the most missing
    level = rows(0.005, 0.40)             # level within the noise, less missing: chosen
    worse = rows(0.2, 0.10)               # least missing, but clearly further from the truth
    best, tied = choose_keep_scan([lowest, level, worse], draws=2000)
    assert best == 1 and tied == [0, 1]
    best, tied = choose_keep_scan([lowest, worse], draws=2000)
    assert best == 0 and tied == [0]
    none = [dict(r, missing_x1e3=None) for r in level]   # no shape with a missing part: Chamfer decides
    assert choose_keep_scan([lowest, none], draws=2000)[0] == 0
