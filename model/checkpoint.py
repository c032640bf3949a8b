"""Load a trained model from a run folder (``checkpoint.pt``) or a shipped checkpoint folder
(``model.pt`` + ``model.json``, as :mod:`model.release` writes): one loader for evaluation,
calibration, figures and export."""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path

import torch

from .files import sha256_file
from .train.loop import TrainConfig, build_model, config_from_dict, load_checkpoint


@dataclasses.dataclass
class Loaded:
    """A trained network in eval mode, its configuration and its provenance."""

    model: torch.nn.Module
    config: TrainConfig
    meta: dict          # a checkpoint folder's model.json, or a run's config, step and calibration


def load_model(path: str | Path) -> Loaded:
    """The model of a run folder or of a checkpoint folder; ValueError if ``path`` is neither or
    its weights do not match the checksum model.json records."""
    path = Path(path)
    if (path / "model.json").is_file() and (path / "model.pt").is_file():
        meta = json.loads((path / "model.json").read_text())
        digest = sha256_file(path / "model.pt")
        if meta.get("weights_sha256") not in (None, digest):
            raise ValueError(f"{path / 'model.pt'}: sha256 {digest} does not match model.json")
        cfg = config_from_dict({"data": "", "out": "", **meta["config"]})
        weights = torch.load(path / "model.pt", map_location="cpu", weights_only=True)
    elif (path / "checkpoint.pt").is_file():
        state = load_checkpoint(path / "checkpoint.pt")
        cfg, weights = config_from_dict(state["config"]), state["model"]
        meta = {"config": {k: v for k, v in state["config"].items() if k not in ("out", "progress")},
                "steps": state.get("step"), "calibration": state.get("calibration"),
                "weights_sha256": None, "source_run": str(path.resolve())}
    else:
        raise ValueError(f"{path}: neither a run folder (checkpoint.pt) nor a checkpoint folder "
                         f"(model.pt + model.json)")
    cfg = dataclasses.replace(cfg, teacher=None)      # the weights already hold the teacher's decoder
    model = build_model(cfg)
    model.load_state_dict(weights)
    return Loaded(model.eval(), cfg, meta)
