"""Recipes: how each shipped model is made, as a small TOML file (``research/recipes/<name>.toml``)
read into the project's own config classes, and run end to end, resumably.

A recipe names its datasets (``[datasets.<name>]``: the options of ``python -m model.data
build``), its training stages in order (``[[stages]]``: a task, a dataset, a
:class:`model.train.config.TrainConfig`'s fields under ``config``, the stage whose result is its
``teacher`` or ``init``, whether its step is chosen on the validation split and how it is
calibrated), and the stage released as the checkpoint (``[release]``: its evaluation's options).
:func:`run_recipe` builds, trains, chooses, calibrates, packages and evaluates; every part resumes
(datasets skip finished records, trainings resume from their checkpoints, chosen and calibrated
folders are kept), so rerunning the same command after an interruption goes on where it stopped.
``smoke`` runs the same recipe at a toy size (two categories, ten shapes each, two steps a
stage): the tests run every recipe so.
"""

from __future__ import annotations

import dataclasses
import hashlib
import tomllib
from pathlib import Path

import torch

from model.data.__main__ import main as build_main
from model.train.config import TrainConfig
from model.train.loop import Trainer

from .calibrate import calibrate, calibrate_keep_scan, calibrate_mask_guide
from .choose import choose

RECIPES_DIR = Path(__file__).resolve().parent / "recipes"
CALIBRATIONS = ("splits", "keep-scan", "mask-guide")
SMOKE_DATA = {"per_category": 10, "categories": ["chair", "airplane"], "views": 2, "render_size": 32,
              "scan_resolution": 48}
"""The toy dataset of a smoke run (the depth stays the recipe's)."""
SMOKE_CONFIG = {"iters": 2, "until": None, "val_every": 2, "ckpt_every": 2, "batch_size": 2, "stream": 0,
                "workers": 1}
"""The toy schedule of a smoke run's stages."""


@dataclasses.dataclass(frozen=True)
class Stage:
    """One training of a recipe: ``task`` (``python -m model.train TASK``) on dataset ``data`` with
    ``config`` (TrainConfig fields), started from stage ``init``'s result or regressed onto stage
    ``teacher``'s; ``choose``: the step with the lowest validation Chamfer distance is its result;
    ``calibrate``: then, in order, its split decisions (``splits``), the decode setting of
    outputs that keep the scan (``keep-scan``), its masks' guided filter (``mask-guide``, on
    ``calibrate_data``, default ``data``)."""

    name: str
    task: str
    data: str
    config: dict
    teacher: str | None = None
    init: str | None = None
    choose: bool = False
    calibrate: tuple[str, ...] = ()
    calibrate_data: str | None = None


@dataclasses.dataclass(frozen=True)
class Recipe:
    """A shipped model's recipe (see the module docstring); ``path`` its file, ``sha256`` its bytes'."""

    name: str
    checkpoint: str
    datasets: dict[str, dict]
    stages: tuple[Stage, ...]
    release: dict
    path: Path
    sha256: str

    @property
    def task(self) -> str:
        """The training task of the released stage."""
        return self.stage(self.release["stage"]).task

    def stage(self, name: str) -> Stage:
        return next(s for s in self.stages if s.name == name)


def recipe_names() -> list[str]:
    return sorted(p.stem for p in RECIPES_DIR.glob("*.toml"))


def load_recipe(name_or_path: str | Path) -> Recipe:
    """A recipe by name (``research/recipes/<name>.toml``) or path; ValueError naming what is wrong."""
    path = Path(name_or_path)
    if not path.suffix:
        path = RECIPES_DIR / f"{name_or_path}.toml"
    if not path.is_file():
        raise ValueError(f"no recipe {name_or_path}; the recipes are {', '.join(recipe_names())}")
    raw = path.read_bytes()
    try:
        doc = tomllib.loads(raw.decode())
        stages = tuple(Stage(**{**s, "calibrate": tuple(s.get("calibrate", ()))}) for s in doc["stages"])
        recipe = Recipe(path.stem, doc["checkpoint"], doc["datasets"], stages, doc["release"], path,
                        hashlib.sha256(raw).hexdigest())
    except (tomllib.TOMLDecodeError, KeyError, TypeError) as exc:
        raise ValueError(f"{path}: not a recipe ({type(exc).__name__}: {exc})") from None
    _check(recipe)
    return recipe


def _check(recipe: Recipe) -> None:
    names = [s.name for s in recipe.stages]
    for i, s in enumerate(recipe.stages):
        for ref in (s.teacher, s.init):
            if ref is not None and ref not in names[:i]:
                raise ValueError(f"{recipe.path}: stage {s.name} starts from {ref}, which is not an earlier stage")
        for d in (s.data, s.calibrate_data or s.data):
            if d not in recipe.datasets:
                raise ValueError(f"{recipe.path}: stage {s.name} reads dataset {d}, which the recipe does not build")
        if set(s.calibrate) - set(CALIBRATIONS):
            raise ValueError(f"{recipe.path}: stage {s.name}: calibrations are {', '.join(CALIBRATIONS)}")
        try:
            TrainConfig(data="", out="", task=s.task, **s.config)
        except TypeError as exc:                          # a setting TrainConfig does not have
            raise ValueError(f"{recipe.path}: stage {s.name}: {exc}") from None
    if recipe.release.get("stage") not in names or recipe.release.get("data") not in recipe.datasets:
        raise ValueError(f"{recipe.path}: [release] names a stage and a dataset of the recipe")


def dataset_flags(settings: dict) -> list[str]:
    """``python -m model.data build``'s options of a recipe's dataset settings."""
    flags = []
    for key, value in settings.items():
        flag = "--" + key.replace("_", "-")
        flags += [flag, *map(str, value)] if isinstance(value, list) else [flag, str(value)]
    return flags


def build_args(settings: dict, out: Path, workers: int) -> list[str]:
    """``python -m model.data``'s arguments that build a recipe's dataset into ``out``."""
    return ["build", "--out", str(out), "--workers", str(workers), "--quiet", *dataset_flags(settings)]


def smoke_recipe(recipe: Recipe) -> Recipe:
    """The recipe at a toy size (:data:`SMOKE_DATA`, :data:`SMOKE_CONFIG`): the same stages and
    settings otherwise, in minutes."""
    datasets = {k: {**v, **SMOKE_DATA, "splits": v.get("splits", ["train", "val", "test"])}
                for k, v in recipe.datasets.items()}
    stages = tuple(dataclasses.replace(s, config={**s.config, **SMOKE_CONFIG}) for s in recipe.stages)
    return dataclasses.replace(recipe, datasets=datasets, stages=stages)


@dataclasses.dataclass
class Made:
    """What a recipe's run made: each dataset's folder and each stage's result folder."""

    data: dict[str, Path]
    results: dict[str, Path]


def run_recipe(recipe: Recipe, workdir: Path, device: str = "cpu", threads: int | None = None,
               workers: int = 1, progress: bool = False, smoke: bool = False) -> Made:
    """Build the datasets and run the stages of ``recipe`` under ``workdir`` (``WORK/data/<name>``,
    ``WORK/<stage>``, its ``-chosen`` and ``-calibrated`` folders), resuming whatever is there.
    ``smoke``: a toy run (:func:`smoke_recipe`), whose outputs may all be empty: then a stage's
    last step stands where no step can be chosen."""
    if threads:
        torch.set_num_threads(threads)
    workdir.mkdir(parents=True, exist_ok=True)
    data = {name: workdir / "data" / name for name in recipe.datasets}
    for name, settings in recipe.datasets.items():
        if build_main(build_args(settings, data[name], workers)):
            raise ValueError(f"the dataset {name} could not be built ({data[name]})")
    results: dict[str, Path] = {}
    for s in recipe.stages:
        results[s.name] = _run_stage(s, data, results, workdir, device, progress, smoke)
    return Made(data, results)


def _run_stage(s: Stage, data: dict[str, Path], results: dict[str, Path], workdir: Path, device: str,
               progress: bool, smoke: bool) -> Path:
    """Train one stage (resuming), then choose its step and calibrate it; its result folder."""
    run = workdir / s.name
    refs = {k: str(results[v]) for k, v in (("teacher", s.teacher), ("init", s.init)) if v is not None}
    cfg = TrainConfig(data=str(data[s.data]), out=str(run), task=s.task, device=device, progress=progress,
                      **{**s.config, **refs})
    trainer = Trainer(cfg)                 # resumes from the run's checkpoint; a finished run stays as it is
    try:
        trainer.run()
    finally:
        trainer.close()
    result = run
    if s.choose:
        chosen = workdir / f"{s.name}-chosen"
        try:
            choose(run, data[s.data], chosen, per_category=4)
            result = chosen
        except ValueError:
            if not smoke:
                raise
    cal_data = str(data[s.calibrate_data or s.data])
    for kind in s.calibrate:
        if kind == "splits":
            out = workdir / f"{s.name}-calibrated"
            calibrate(str(result), cal_data, str(out))
            result = out
        elif kind == "keep-scan":
            calibrate_keep_scan(str(result), cal_data, per_category=10)
        else:
            calibrate_mask_guide(str(result), cal_data)
    return result
