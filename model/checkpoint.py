"""Load a trained model from a run folder (``checkpoint.pt``) or a shipped checkpoint folder
(``model.pt`` + ``model.json``, as :mod:`research.release` writes): one loader for evaluation,
calibration, figures and export.  Reading the files is :func:`model.train.config.read_run`'s;
this builds the task's network from them."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import torch

from .train.config import TrainConfig, read_run
from .train.tasks import TASKS


@dataclasses.dataclass
class Loaded:
    """A trained network in eval mode, its configuration and its provenance."""

    model: torch.nn.Module
    config: TrainConfig
    meta: dict          # a checkpoint folder's model.json, or a run's config, step and calibration


def load_model(path: str | Path) -> Loaded:
    """The model of a run folder or of a checkpoint folder; ValueError if ``path`` is neither or
    its weights do not match the checksum model.json records."""
    saved = read_run(path)
    cfg = dataclasses.replace(saved.config, teacher=None)   # the weights already hold the teacher's decoder
    model = TASKS[cfg.task].build_model(cfg)
    model.load_state_dict(saved.weights)
    return Loaded(model.eval(), cfg, saved.meta)
