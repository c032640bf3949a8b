"""Produce a shipped model with one resumable command: its recipe run end to end (data, training,
the step chosen on validation, calibration), then the checkpoint and its provenance under
``models/checkpoints/`` and its evaluation.

    python -m research.release RECIPE --workdir DIR [--out models/checkpoints/<name>] [--device cuda]
        [--smoke] [--run RUN [--data DIR]]

RECIPE is a recipe's name (``research/recipes/<name>.toml``: image-to-shape, completion,
classify, foreground) or a recipe file; :mod:`research.recipe` says what one holds and how it
runs.  Every step resumes, so rerunning the same command after an interruption continues where it
stopped.  ``--smoke`` runs the recipe at a toy size (the tests do).

With ``--run``, an existing run (trained by hand: partly on a GPU, or resumed with other data) is
packaged instead of training by the recipe; the recipe's release dataset is still built (its
manifest is the provenance, its test split the evaluation), and model.json records the run's own
configuration and steps, with no recipe training command.  ``--data`` with ``--run`` names the
dataset the run was trained on instead (a larger or deeper one than the recipe's: its manifest is
then the provenance and its test split the evaluation, and no build command is recorded).
"""

from __future__ import annotations

import json
import shlex
import sys
from pathlib import Path

from model.cli import command_parser
from model.data.__main__ import main as build_main
from model.files import json_text, sha256_file, write_atomic
from model.train.config import INIT_FILE, STEPS_DIR, TrainConfig, read_run, write_weights

from .evaluate import main as evaluate_main
from .recipe import Recipe, build_args, dataset_flags, load_recipe, recipe_names, run_recipe, smoke_recipe

CHECKPOINT_FORMAT = 1


def package(run: Path, data: Path, out: Path, recipe: Recipe, command: list[str], by_recipe: bool = True,
            data_by_recipe: bool = True) -> dict:
    """Write ``out/model.pt`` (the plain state_dict in half precision) and ``out/model.json``
    (provenance; its evaluation is added by :func:`record_evaluation`, measured on exactly these
    weights).  The decode settings chosen for the run's weights on the validation split
    (``research.calibrate --keep-scan``, ``--mask-guide``) go with them.  ``by_recipe=False``: the run
    was not trained by the recipe, so no training command is recorded (its configuration and steps
    are); ``data_by_recipe=False``: nor was ``data`` built by the recipe (the manifest's settings are
    recorded)."""

    saved = read_run(run)                  # a run folder, or a checkpoint folder such as a step the run kept
    config = saved.meta["config"]
    calibration, teacher = saved.meta.get("calibration"), config.get("teacher")
    if calibration is None and teacher and Path(teacher).is_dir():
        calibration = read_run(teacher).meta.get("calibration")    # a refined image model: its teacher's decoder
    manifest = json.loads((data / "manifest.json").read_text())
    release_data = recipe.datasets[recipe.release["data"]]
    meta = {
        "format": CHECKPOINT_FORMAT,
        "task": recipe.checkpoint,
        "config": {k: _named_here(v) if k in ("teacher", "init") else v
                   for k, v in config.items() if k not in ("data", "out", "progress")},
        "steps": saved.meta["steps"],
        "init": _paths_named_here(_init_of(run)),
        "calibration": calibration,
        "command": "python -m research.release " + " ".join(shlex.quote(c) for c in command),
        "recipe": {"file": f"research/recipes/{recipe.path.name}", "sha256": recipe.sha256} if by_recipe else None,
        "train_command": f"python -m research.release {recipe.name} --workdir WORKDIR" if by_recipe else None,
        "data": {"build": manifest["config"], "source": "procedural",
                 "build_command": ("python -m model.data build " + " ".join(dataset_flags(release_data))
                                   if data_by_recipe else None),
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
        "python -m research.release image-to-shape --workdir work/image --device cuda --workers 8",
        "python -m research.release classify --workdir work/classify-smoke --smoke --out work/classify-smoke/ckpt"])
    ap.add_argument("recipe", help=f"a recipe's name ({', '.join(recipe_names())}) or a recipe file (.toml)")
    ap.add_argument("--workdir", required=True, help="folder for the datasets, the runs and the evaluation")
    ap.add_argument("--out", default=None, help="where model.pt and model.json go (default models/checkpoints/<name>)")
    ap.add_argument("--workers", type=int, default=1, help="dataset build processes (default 1)")
    ap.add_argument("--threads", type=int, default=1, help="torch threads for training (default 1)")
    ap.add_argument("--device", default="cpu", help="training device: cpu (default), cuda or cuda:N")
    ap.add_argument("--smoke", action="store_true", help="the recipe at a toy size (two categories, ten shapes "
                    "each, two steps a stage): a check that it runs end to end")
    ap.add_argument("--run", default=None, help="package this run folder (its checkpoint.pt), or checkpoint folder "
                    "such as a step a run kept (RUN/steps/<step>), instead of training by the recipe")
    ap.add_argument("--data", default=None, help="with --run: the dataset folder the run was trained on, "
                    "evaluated on its test split, instead of building the recipe's")
    args = ap.parse_args(argv)
    try:
        recipe = load_recipe(args.recipe)
        recipe = smoke_recipe(recipe) if args.smoke else recipe
        work = Path(args.workdir)
        out = Path(args.out or Path("models") / "checkpoints" / recipe.checkpoint)
        final, data = _made(recipe, work, args)
        package(final, data, out, recipe, sys.argv[1:] if argv is None else argv, by_recipe=args.run is None,
                data_by_recipe=args.data is None)
    except (ValueError, FileNotFoundError) as exc:
        print(f"python -m research.release: {exc}", file=sys.stderr)
        return 2
    work.mkdir(parents=True, exist_ok=True)
    results_path = work / "test.json"
    code = evaluate_main([str(out), "--data", str(data), "--out", str(results_path), *recipe.release["evaluate"]])
    if code:
        return code
    meta = record_evaluation(out, json.loads(results_path.read_text()))
    print(f"{out}: {meta['task']}, {meta['parameters']:,} parameters, {_figure(meta['evaluation'])}")
    return 0


def _made(recipe: Recipe, work: Path, args) -> tuple[Path, Path]:
    """The folder to package and the dataset to evaluate it on: the recipe run (or, with --run, the
    run given, checked before anything is built, and the release dataset)."""
    if args.run is None:
        if args.data is not None:
            raise ValueError("--data goes with --run")
        made = run_recipe(recipe, work, args.device, args.threads, args.workers, smoke=args.smoke)
        return made.results[recipe.release["stage"]], made.data[recipe.release["data"]]
    final = Path(args.run)
    config = read_run(final).config
    if config.task != recipe.task:
        raise ValueError(f"{final} is a {config.task} run, not a {recipe.task} run")
    if args.data is not None:
        data = Path(args.data)
        problem = _dataset_problem(data, final, config)
        if problem:
            raise ValueError(problem)
        return final, data
    data = work / "data" / recipe.release["data"]
    if build_main(build_args(recipe.datasets[recipe.release["data"]], data, args.workers)):
        raise ValueError(f"the dataset {data} could not be built")
    return final, data


def _figure(ev: dict) -> str:
    if "voted_accuracy" in ev:
        return f"test accuracy {ev['accuracy']:.4f} ({ev['voted_accuracy']:.4f} voted over 12 rotations)"
    if "mask_iou_median" in ev:
        return f"test photos' mask IoU {ev['mask_iou_category_mean']:.4f}"
    chamfer = ev["chamfer_x1e3_category_mean"]
    return "test Chamfer x1e3 " + ("none: every output was empty" if chamfer is None else f"{chamfer:.3f}")


if __name__ == "__main__":
    sys.exit(main())
