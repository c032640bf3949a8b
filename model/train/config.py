"""A run's configuration and the reading of saved runs: below the tasks, the loop, evaluation and
export, so that each of them can load a run without importing another.

A run folder holds ``checkpoint.pt`` (written by :meth:`model.train.loop.Trainer.save`); a
checkpoint folder holds ``model.pt`` (a state dict, float32 or half precision) and ``model.json``
(written by :mod:`research.release`).  :func:`read_run` reads either into a :class:`SavedRun`;
building the network from it is the task's (:func:`model.checkpoint.load_model`).
"""

from __future__ import annotations

import json
import multiprocessing
from dataclasses import dataclass, field
from pathlib import Path

import torch

from ..files import atomic_path, json_text, sha256_file, write_atomic
from ..image.frame import ImageSpec


@dataclass
class TrainConfig:
    """Everything a run depends on; saved to RUN/config.json and checked on resume."""

    data: str
    depth: int
    arch: str
    out: str
    iters: int = 2000
    epochs: float | None = None
    until: int | None = None                   # end at this step (None: iters); the schedule spans iters
    batch_size: int = 8
    optimizer: str = "adam"
    lr: float | None = None
    weight_decay: float = 0.0
    val_every: int = 200
    ckpt_every: int = 100
    latent: int = 128
    channels: int = 8
    structure_loss: str = "ce"
    pred_hidden: int = 8
    decoder_blocks: int = 1
    seed: int = 0
    limit: int | None = None
    progress: bool = True
    task: str = "autoencoder"
    categories: list[str] | None = None       # train on these categories only
    encoder: str = "resnet18"                  # image task: the image encoder
    encoder_width: int | None = None           # image task: its width (None: the encoder's default)
    image_size: int = 128                      # image task: encoder input side
    background_share: float = 0.5              # image task: samples composited onto a background
    teacher: str | None = None                 # image task: regress onto this autoencoder's (or image model's) codes
    photo_share: float = 0.0                   # image task: samples made photos, brought back with an imperfect mask
    foreground_ratio: float | None = None      # image task: share of the square the object fills (None: 0.9)
    workers: int = 1                           # processes reading the dataset and building octree caches
    loader_workers: int = 0                    # processes preparing batches ahead of the training step
    device: str = "cpu"                        # where the network trains (cpu, cuda, cuda:N)
    amp: bool = False                          # bfloat16 autocast of the forward pass
    up: str = "y"                              # classify: the up axis of the dataset's shapes
    skips: bool = False                        # completion: output-guided skip connections
    stream: int = 0                            # shapes kept in memory when streaming records (0: all; not classify)
    crop_share: float = 0.0                    # foreground: samples that are a second look's view
    skeleton_weight: float = 0.0               # foreground: weight of the skeleton recall loss (thin parts)
    init: str | None = None                    # a run or checkpoint folder whose weights a new run starts from

    def image_spec(self) -> ImageSpec:
        """The preprocessing of an image task's encoder (its input side and framing)."""
        if self.foreground_ratio is None:
            return ImageSpec(size=self.image_size)
        return ImageSpec(size=self.image_size, margin=round((1 - self.foreground_ratio) / 2, 6))

    def check(self) -> None:
        """Raise ValueError naming the first generic setting that cannot train (the task checks
        its own: :func:`model.train.tasks.check_config`)."""
        if self.encoder_width is not None and self.encoder_width < 1:
            raise ValueError(f"--encoder-width must be at least 1, got {self.encoder_width}")
        for name in ("iters", "batch_size", "val_every", "ckpt_every", "latent", "channels", "pred_hidden",
                     "decoder_blocks", "workers"):
            if getattr(self, name) < 1:
                raise ValueError(f"--{name.replace('_', '-')} must be at least 1, got {getattr(self, name)}")
        if self.limit is not None and self.limit < 1:
            raise ValueError(f"--limit must be at least 1, got {self.limit}")
        if self.until is not None and self.until < 1:
            raise ValueError(f"--until must be at least 1, got {self.until}")
        if self.epochs is not None and not self.epochs > 0:
            raise ValueError(f"--epochs must be positive, got {self.epochs}")
        if self.init is not None and self.teacher is not None:
            raise ValueError("--init and --teacher both give the starting weights; give one")
        if self.lr is not None and not self.lr > 0:
            raise ValueError(f"--lr must be positive, got {self.lr}")
        if not self.weight_decay >= 0:
            raise ValueError(f"--weight-decay must be >= 0, got {self.weight_decay}")
        if self.loader_workers < 0:
            raise ValueError(f"--loader-workers must be 0 or more, got {self.loader_workers}")
        if (self.loader_workers > 0 or self.workers > 1) and "fork" not in multiprocessing.get_all_start_methods():
            raise ValueError("--workers and --loader-workers need the fork start method (Linux); leave them out")
        try:
            device = torch.device(self.device)
        except (RuntimeError, ValueError):
            raise ValueError(f"--device {self.device!r} is not a device; use cpu, cuda or cuda:N") from None
        if device.type not in ("cpu", "cuda"):
            raise ValueError(f"--device {self.device!r}: training runs on cpu or cuda")
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"--device {self.device}: this torch ({torch.__version__}) sees no CUDA GPU; "
                             "train with --device cpu")
        out = Path(self.out)
        if out.exists() and not out.is_dir():
            raise ValueError(f"--out {self.out} is a file; give a run folder")


def load_checkpoint(path: Path) -> dict:
    """A checkpoint written by :meth:`Trainer.save`: FileNotFoundError if it is missing,
    ValueError if it cannot be read or is something else."""
    if not path.is_file():
        raise FileNotFoundError(f"{path} not found: train first with python -m model.train")
    try:
        state = torch.load(path, map_location="cpu", weights_only=False)
    except Exception as exc:  # torch raises many types for a damaged file
        raise ValueError(f"{path} is not a readable checkpoint ({type(exc).__name__}); "
                         "delete it or use another run folder") from None
    if not isinstance(state, dict) or not {"model", "config", "step"} <= set(state):
        raise ValueError(f"{path} is not a checkpoint of python -m model.train")
    return state


STEPS_DIR = "steps"
"""The sub-folder of a run holding a checkpoint folder per validated step (:meth:`Trainer.snapshot`)."""

LEGACY_DEFAULTS = {"structure_loss": "ce", "pred_hidden": 8, "decoder_blocks": 1, "task": "autoencoder"}
"""Settings of runs saved before the setting existed (the paper's values)."""


def config_from_dict(saved: dict) -> TrainConfig:
    """The TrainConfig of a saved run, older runs' missing settings filled with what they used."""
    known = TrainConfig.__dataclass_fields__
    return TrainConfig(**{**LEGACY_DEFAULTS, **{k: v for k, v in saved.items() if k in known}})


def half_precision(weights: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """A state dict with its floating tensors stored as float16 (how shipped checkpoints are kept:
    half the bytes; :func:`read_run` returns them as float32, and bundles are exported from them)."""
    return {k: v.half() if v.is_floating_point() else v for k, v in weights.items()}


def write_weights(out: Path, weights: dict[str, torch.Tensor], meta: dict) -> dict:
    """Write a checkpoint folder that :func:`read_run` reads: ``out/model.pt`` (``weights`` in half
    precision) and ``out/model.json`` (``meta`` with the weights' file name, checksum, dtype and
    parameter count added), each atomically, the weights first.  Returns the written meta."""
    out.mkdir(parents=True, exist_ok=True)
    path = out / "model.pt"
    with atomic_path(path) as tmp:
        torch.save(half_precision(weights), tmp)
    meta = {**meta, "weights": path.name, "weights_sha256": sha256_file(path), "weights_dtype": "float16",
            "parameters": int(sum(v.numel() for v in weights.values() if v.is_floating_point()))}
    write_atomic(out / "model.json", json_text(meta).encode())
    return meta


@dataclass
class SavedRun:
    """A saved run's configuration, float32 weights and provenance (``meta``: a checkpoint folder's
    model.json, or a run's config, step and calibration)."""

    config: TrainConfig
    weights: dict[str, torch.Tensor]
    meta: dict = field(default_factory=dict)


KEEP_SCAN_FILE = "keep_scan.json"
"""A run folder's decode setting for completions that keep the scan (a checkpoint folder keeps it
in model.json's ``keep_scan``), written by ``python -m research.calibrate --keep-scan``."""


MASK_GUIDE_FILE = "mask_guide.json"
"""A foreground run folder's guided filter of its masks (a checkpoint folder keeps it in
model.json's ``mask_guide``), written by ``python -m research.calibrate --mask-guide``."""


INIT_FILE = "init.json"
"""A run folder's record of the weights it started from (``--init``): the folder given, its
weights' sha256 (a checkpoint folder's) and steps; :mod:`research.release` copies it to model.json."""


def read_run(path: str | Path) -> SavedRun:
    """The configuration and weights of a run folder or a checkpoint folder.  ValueError if ``path``
    is neither, or its weights do not match the checksum model.json records.  Half-precision
    weights (how shipped checkpoints are stored) are returned as float32."""
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
        for key, name in (("keep_scan", KEEP_SCAN_FILE), ("mask_guide", MASK_GUIDE_FILE)):
            if (path / name).is_file():
                meta[key] = json.loads((path / name).read_text())
    else:
        raise ValueError(f"{path}: neither a run folder (checkpoint.pt) nor a checkpoint folder "
                         f"(model.pt + model.json)")
    weights = {k: v.float() if v.is_floating_point() else v for k, v in weights.items()}
    return SavedRun(cfg, weights, meta)
