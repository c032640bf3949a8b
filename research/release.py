"""Produce a shipped model from scratch with one resumable command: data, training, split
calibration, evaluation, and the checkpoint + provenance JSON under ``models/checkpoints/``.

    python -m research.release {image,completion,classify,foreground} --workdir DIR [--out models/checkpoints/<task>]
        [--run RUN [--data DIR]]

With ``--run``, an existing run (trained by hand: partly on a GPU, or resumed with other data) is
packaged instead of training by the recipe; the dataset is still built (its manifest is the
provenance, its test split the evaluation), and model.json records the run's own configuration
and steps, with no recipe training command.  ``--data`` with ``--run`` names the dataset the run
was trained on instead (a larger or deeper one than the recipe's: its manifest is then the
provenance and its test split the evaluation, and no build command is recorded).

Every step resumes: the dataset build skips finished records, training resumes from its
checkpoint, so rerunning the same command after an interruption continues where it stopped.
The recipe (dataset settings, training settings, seed) is fixed per model in :data:`RECIPES`.
"""

from __future__ import annotations

import json
import shlex
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from model.cli import command_parser
from model.data.__main__ import main as build_main
from model.files import json_text, sha256_file, write_atomic
from model.train.__main__ import main as train_main
from model.train.config import INIT_FILE, STEPS_DIR, read_run, write_weights

from .calibrate import main as calibrate_main
from .evaluate import main as evaluate_main

if TYPE_CHECKING:
    from model.train.config import TrainConfig

CHECKPOINT_FORMAT = 1


@dataclass(frozen=True)
class Recipe:
    """How one shipped model is made: the dataset build and training arguments (CLI form)."""

    task: str
    build: list[str]
    train: list[str]
    evaluate: list[str] = field(default_factory=list)
    calibrate: bool = True          # fold the split-count calibration (research.calibrate) into the weights
    teacher: list[str] | None = None  # an autoencoder trained first; ``train`` regresses onto its codes
    refine: list[str] | None = None   # a last image training with the (calibrated) run as its teacher


RECIPES: dict[str, Recipe] = {
    "image": Recipe(
        task="image-to-shape",
        build=["--per-category", "100", "--depth", "6", "--seed", "0"],
        # The image encoder is regressed onto the latent codes of an Adaptive O-CNN autoencoder and
        # uses its decoder: at 4,000 steps this gives 8.7 (4.1 after ICP) against 16.0 (9.8) for the
        # same network trained end to end (docs/journal/2026-11-experiments.md).
        teacher=["autoencoder", "--depth", "6", "--arch", "aocnn", "--iters", "4000", "--batch-size", "8",
                 "--val-every", "500", "--ckpt-every", "250", "--seed", "0", "--structure-loss", "balanced",
                 "--pred-hidden", "32"],
        train=["image", "--depth", "6", "--encoder", "resnet18", "--decoder", "aocnn", "--iters", "4000",
               "--batch-size", "8", "--val-every", "500", "--ckpt-every", "250", "--seed", "0",
               "--structure-loss", "balanced", "--pred-hidden", "32"],
        # Then retrained for photographs: half the samples are photo-like composites cut out again
        # with imperfect masks (the service's background removal), regressed onto the calibrated
        # model's codes of the clean renders, framed at the foreground ratio 0.85 (docs/journal/2026-11-experiments.md).
        refine=["image", "--depth", "6", "--encoder", "resnet18", "--decoder", "aocnn", "--iters", "4000",
                "--batch-size", "8", "--val-every", "500", "--ckpt-every", "100", "--seed", "0",
                "--structure-loss", "balanced", "--pred-hidden", "32", "--photo-share", "0.5",
                "--foreground-ratio", "0.85", "--lr", "5e-4"],
        evaluate=["--split", "test", "--icp"]),
    "foreground": Recipe(
        task="foreground",
        build=["--per-category", "100", "--depth", "6", "--seed", "0"],
        # The image bundle's background removal, trained on photo-like composites of the renders;
        # python -m export ... --foreground models/checkpoints/foreground puts it in the bundle (int8).
        # Width 16 (1.23 M parameters).  The shipped network was trained by hand with this schedule:
        # its first 3,250 steps on a GPU with the depth-7 set of ten times the shapes
        # (scripts/gpu-train), the rest resumed on the CPU with this dataset, then packaged with
        # --run (docs/journal/2026-11-experiments.md); this recipe alone trains the same network on this dataset.
        train=["foreground", "--depth", "6", "--width", "16", "--iters", "15000", "--batch-size", "16",
               "--val-every", "1000", "--ckpt-every", "250", "--seed", "0"],
        evaluate=["--split", "test"], calibrate=False),
    "completion": Recipe(
        task="completion",
        build=["--per-category", "100", "--depth", "6", "--seed", "0"],
        # Trained end to end in the partial scan's frame: a teacher autoencoder's codes live in the
        # complete shape's own frame, which a partial scan does not reveal (docs/journal/2026-11-experiments.md).  With
        # output-guided skip connections: validation Chamfer x1e3 0.280 against 1.332 without them
        # (0.373 as served with the scan kept), at the same 4,000 steps; 8,000 steps (shipped, packaged
        # from a run of exactly these settings with --run): 0.251 alone, 0.207 served (docs/journal/2026-11-experiments.md).
        train=["completion", "--depth", "6", "--arch", "aocnn", "--iters", "8000", "--batch-size", "8",
               "--val-every", "1000", "--ckpt-every", "250", "--seed", "0", "--structure-loss", "balanced",
               "--pred-hidden", "32", "--workers", "2", "--skips"],
        evaluate=["--split", "test"]),
    "classify": Recipe(
        task="classify",
        build=["--per-category", "100", "--depth", "6", "--seed", "0"],
        train=["classify", "--depth", "6", "--arch", "aocnn", "--iters", "2000", "--batch-size", "16",
               "--val-every", "250", "--ckpt-every", "250", "--seed", "0"],
        evaluate=["--split", "test"], calibrate=False),
}


def package(run: Path, data: Path, out: Path, recipe: Recipe, command: list[str], by_recipe: bool = True,
            data_by_recipe: bool = True) -> dict:
    """Write ``out/model.pt`` (the plain state_dict in half precision) and ``out/model.json``
    (provenance; its evaluation is added by :func:`record_evaluation`, measured on exactly these
    weights).  The decode settings chosen for the run's weights on the validation split
    (``research.calibrate --keep-scan``, ``--mask-guide``) go with them.  ``by_recipe=False``: the run
    was not trained by the recipe's commands, so none are recorded (its configuration and steps
    are); ``data_by_recipe=False``: nor was ``data`` built by its build command (the manifest's
    settings are recorded)."""

    saved = read_run(run)                  # a run folder, or a checkpoint folder such as a step the run kept
    config = saved.meta["config"]
    calibration, teacher = saved.meta.get("calibration"), config.get("teacher")
    if calibration is None and teacher and Path(teacher).is_dir():
        calibration = read_run(teacher).meta.get("calibration")    # a refined image model: its teacher's decoder
    manifest = json.loads((data / "manifest.json").read_text())
    meta = {
        "format": CHECKPOINT_FORMAT,
        "task": recipe.task,
        "config": {k: _named_here(v) if k in ("teacher", "init") else v
                   for k, v in config.items() if k not in ("data", "out", "progress")},
        "steps": saved.meta["steps"],
        "init": _paths_named_here(_init_of(run)),
        "calibration": calibration,
        "command": "python -m research.release " + " ".join(shlex.quote(c) for c in command),
        "train_command": ("python -m model.train " + " ".join(shlex.quote(c) for c in recipe.train)
                          + (" --teacher TEACHER_RUN" if recipe.teacher else "")) if by_recipe else None,
        "teacher_command": ("python -m model.train " + " ".join(shlex.quote(c) for c in recipe.teacher)
                            + " --out TEACHER_RUN") if recipe.teacher and by_recipe else None,
        "refine_command": ("python -m model.train " + " ".join(shlex.quote(c) for c in recipe.refine)
                           + " --teacher CALIBRATED_RUN") if recipe.refine and by_recipe else None,
        "data": {"build": manifest["config"], "source": "procedural",
                 "build_command": "python -m model.data build " + " ".join(recipe.build) if data_by_recipe else None,
                 "splits": manifest.get("splits"),
                 "manifest_sha256": sha256_file(data / "manifest.json")},
        "evaluation": None,
    }
    for key in ("keep_scan", "mask_guide"):     # decode settings chosen on validation for these weights
        if saved.meta.get(key) is not None:
            meta[key] = saved.meta[key]
    return write_weights(out, saved.weights, meta)


def _named_here(value):
    """A run's absolute path (the teacher or the start it was trained from) as the current folder
    names it: relative to it, or through one of its links (``runs -> /disk/runs`` gives
    ``runs/ae7``), so provenance names no machine's folders; anything else unchanged."""
    if not isinstance(value, str) or not Path(value).is_absolute():
        return value
    here, path = Path.cwd(), Path(value).resolve()
    roots = [(".", here.resolve())] + [(link.name, link.resolve()) for link in here.iterdir() if link.is_symlink()]
    for name, root in roots:
        if path.is_relative_to(root):
            return str(Path(name) / path.relative_to(root))
    return value


def _paths_named_here(record: dict | None) -> dict | None:
    """An init record (``init.json``: the folder a run started from, nested for a chain of
    starts) with every ``path`` named as :func:`_named_here` names it."""
    if record is None:
        return None
    return {k: _paths_named_here(v) if isinstance(v, dict) else _named_here(v) if k == "path" else v
            for k, v in record.items()}


def _init_of(run: Path) -> dict | None:
    """The weights ``run`` started from (its ``init.json``; a step the run kept, ``RUN/steps/<step>``,
    reads its run's), or None for random weights."""

    for folder in (run, run.parent.parent if run.parent.name == STEPS_DIR else None):
        if folder is not None and (folder / INIT_FILE).is_file():
            return json.loads((folder / INIT_FILE).read_text())
    return None


def record_evaluation(out: Path, results: dict) -> dict:
    """Add the test figures (``python -m research.evaluate`` of the checkpoint folder ``out``) to its
    model.json, per-shape rows left out."""
    meta = json.loads((out / "model.json").read_text())
    meta["evaluation"] = {k: v for k, v in results.items() if k not in ("per_shape", "run")}
    write_atomic(out / "model.json", json_text(meta).encode())
    return meta


def _dataset_problem(data: Path, run: Path, config: TrainConfig) -> str | None:
    """Why ``data`` cannot be the dataset of ``run`` (no manifest, another depth, or not the dataset
    the run was trained on where that one is here to compare), or None; ``config`` is the run's."""
    manifest = data / "manifest.json"
    if not manifest.is_file():
        return f"--data {data}: no manifest.json (a dataset folder of python -m model.data build)"
    depth = json.loads(manifest.read_text())["config"]["depth"]
    if config.task != "foreground" and depth != config.depth:      # the foreground network reads renders
        return f"--data {data} was built at depth {depth}, but {run} was trained at depth {config.depth}"
    trained_on = Path(config.data) / "manifest.json" if config.data else None
    here = config.task != "foreground" and trained_on is not None and trained_on.is_file()
    if here and sha256_file(trained_on) != sha256_file(manifest):
        return f"--data {data} is not the dataset {run} was trained on ({config.data})"
    return None


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.release", __doc__, [
        "python -m research.release completion --workdir work/completion",
        "python -m research.release image --workdir work/image --workers 2"])
    ap.add_argument("model", choices=sorted(RECIPES), help="which shipped model to make")
    ap.add_argument("--workdir", required=True, help="folder for the dataset, the run and its evaluation")
    ap.add_argument("--out", default=None, help="where model.pt and model.json go "
                    "(default models/checkpoints/<task>)")
    ap.add_argument("--workers", type=int, default=1, help="dataset build processes (default 1)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads for training (default 1)")
    ap.add_argument("--run", default=None, help="package this run folder (its checkpoint.pt), or checkpoint folder "
                    "such as a step a run kept (RUN/steps/<step>), instead of training by the recipe")
    ap.add_argument("--data", default=None, help="with --run: the dataset folder the run was trained on, "
                    "evaluated on its test split, instead of building the recipe's")
    args = ap.parse_args(argv)
    recipe = RECIPES[args.model]
    work = Path(args.workdir)
    data, results_path = Path(args.data or work / "data"), work / "test.json"
    teacher = work / "teacher"
    run = work / ("student" if recipe.teacher else "run")
    final = work / "run-calibrated" if recipe.calibrate else run
    out = Path(args.out or Path("models") / "checkpoints" / recipe.task)

    if args.run is not None:                       # a run trained by hand: checked before anything is built
        final = Path(args.run)
        try:
            config = read_run(final).config
        except (FileNotFoundError, ValueError) as exc:
            print(f"python -m research.release: --run: {exc}", file=sys.stderr)
            return 2
        if config.task != recipe.train[0]:
            print(f"python -m research.release: {final} is a {config.task} run, not a {recipe.train[0]} run", file=sys.stderr)
            return 2
    if args.data is not None:
        problem = _dataset_problem(data, final, config) if args.run is not None else "--data goes with --run"
        if problem:
            print(f"python -m research.release: {problem}", file=sys.stderr)
            return 2
    threads = ["--threads", str(args.threads), "--quiet"]
    steps = [] if args.data else [(build_main, ["build", "--out", str(data), "--workers", str(args.workers),
                                                "--quiet", *recipe.build])]
    if args.run is None:
        if recipe.teacher:
            steps.append((train_main, [*recipe.teacher, "--data", str(data), "--out", str(teacher), *threads]))
        steps.append((train_main, [*recipe.train, "--data", str(data), "--out", str(run), *threads,
                                   *(["--teacher", str(teacher)] if recipe.teacher else [])]))
        if recipe.calibrate:
            steps.append((calibrate_main, [str(run), "--data", str(data), "--out", str(final)]))
        if recipe.refine:
            steps.append((train_main, [*recipe.refine, "--data", str(data), "--out", str(work / "refined"), *threads,
                                       "--teacher", str(final)]))
            final = work / "refined"
    work.mkdir(parents=True, exist_ok=True)
    for fn, fn_args in steps:
        code = fn(fn_args)
        if code:
            return code
    package(final, data, out, recipe, sys.argv[1:] if argv is None else argv, by_recipe=args.run is None,
            data_by_recipe=args.data is None)
    code = evaluate_main([str(out), "--data", str(data), "--out", str(results_path), *recipe.evaluate])
    if code:
        return code
    meta = record_evaluation(out, json.loads(results_path.read_text()))
    ev = meta["evaluation"]
    figure = (f"test accuracy {ev['accuracy']:.4f} ({ev['voted_accuracy']:.4f} voted over 12 rotations)"
              if "voted_accuracy" in ev else f"test photos' mask IoU {ev['mask_iou_category_mean']:.4f}"
              if "mask_iou_median" in ev else "test Chamfer x1e3 " + (
                  "none: every output was empty" if ev["chamfer_x1e3_category_mean"] is None
                  else f"{ev['chamfer_x1e3_category_mean']:.3f}"))
    print(f"{out}: {meta['task']}, {meta['parameters']:,} parameters, {figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
