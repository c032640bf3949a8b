"""Training curves of runs: per loss term, the training loss (moving average) and the validation
loss against the step, one panel per term, every run in its own colour; with ``--chamfer``, also
the validation Chamfer distance of every validated step.

    python -m research.curves RUN [RUN ...] --out PNG [--labels NAME ...] [--terms total ...] [--window 50]
        [--chamfer DATA [--per-category 4] [--resolution 128]]

Reads each run folder's ``metrics.jsonl`` (written by ``python -m model.train``: a row per logged
training step and per validation).  A run that was interrupted and resumed logs some steps twice;
the last row of each (split, step) counts.  The legend gives each run's last step and its
training time.  ``--chamfer DATA`` measures the weights kept at each validated step
(``RUN/steps/<step>/``) with :func:`research.evaluate.evaluate` on the first ``--per-category``
validation shapes of each category of DATA (the panel ``chamfer_x1e3``: category mean x 10^3), keeps
each figure beside its weights (``chamfer.json``, reused while weights and settings are the same) and
prints the step with the lowest: the checkpoint chosen on the validation split.
"""

from __future__ import annotations

import hashlib
import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.cli import command_parser
from model.files import atomic_path, json_text, sha256_file, write_atomic
from model.train.config import STEPS_DIR, read_run

from .evaluate import EvalOptions, evaluate

NOT_TERMS = {"step", "split", "lr", "seconds"}


@dataclass
class RunCurves:
    """One run's logged values: per split ('train', 'val'), ascending steps and each term's values
    (NaN where a row lacks the term).  Invariant: every array of a split has the length of its steps."""

    name: str
    steps: dict[str, np.ndarray]
    values: dict[str, dict[str, np.ndarray]]
    seconds: float | None           # wall time of its training processes, summed

    def terms(self, split: str) -> list[str]:
        return list(self.values.get(split, {}))


def read_curves(run: str | Path, name: str | None = None) -> RunCurves:
    """The curves of a run folder (ValueError naming what is missing or unreadable)."""
    path = Path(run) / "metrics.jsonl"
    if not path.is_file():
        raise ValueError(f"{run}: no metrics.jsonl (a run folder of python -m model.train)")
    rows: dict[tuple[str, int], dict] = {}
    clocks: list[float] = []                    # the train rows' seconds, in the order logged
    for n, line in enumerate(path.read_text().splitlines(), 1):
        if not line.strip():
            continue
        try:
            row = json.loads(line)
            key = (str(row["split"]), int(row["step"]))
        except (json.JSONDecodeError, KeyError, TypeError, ValueError):
            raise ValueError(f"{path}:{n}: not a metrics row") from None
        rows[key] = row                         # a resumed run's repeated step: the last row counts
        if key[0] == "train" and isinstance(row.get("seconds"), (int, float)):
            clocks.append(float(row["seconds"]))
    if not rows:
        raise ValueError(f"{path}: no rows yet")
    steps, values = {}, {}
    for split in sorted({s for s, _ in rows}):
        keyed = sorted((step, row) for (s, step), row in rows.items() if s == split)
        steps[split] = np.array([step for step, _ in keyed])
        names = sorted({k for _, row in keyed for k, v in row.items()
                        if k not in NOT_TERMS and isinstance(v, (int, float))})
        values[split] = {k: np.array([float(row.get(k, np.nan)) for _, row in keyed]) for k in names}
    return RunCurves(name or Path(run).name, steps, values, _wall_seconds(clocks))


def _wall_seconds(clocks: list[float]) -> float | None:
    """The training's wall time over all its processes: each process logs the seconds since it
    started, so a resumed run's ``clocks`` start again from 0; the last value of each such stretch adds up."""
    if not clocks:
        return None
    return sum(a for a, b in zip(clocks, clocks[1:]) if b < a) + clocks[-1]


CHAMFER_TERM = "chamfer_x1e3"


def validation_chamfer(run: str | Path, data: str | Path, per_category: int = 4,
                       resolution: int = 128, foreground: str | Path | None = None) -> dict[int, float]:
    """Step -> validation Chamfer distance (x 10^3, category mean) of each step a run kept its
    weights at (``RUN/steps/<step>/``, :meth:`model.train.loop.Trainer.snapshot`), measured on the
    first ``per_category`` shapes of each category of ``data``'s validation split (NaN where every
    output was empty); each figure is kept in ``chamfer.json`` beside its weights and reused while
    the weights, the settings and the data are the same.  ``foreground`` (image models): measured
    as served on the shapes' photo-like views instead, their backgrounds removed by this foreground
    network (``evaluate(photos=True, foreground=...)``), kept in ``chamfer-photos.json``."""

    manifest = Path(data) / "manifest.json"
    if not manifest.is_file():
        raise ValueError(f"--chamfer {data}: no manifest.json (a dataset folder of python -m model.data build)")
    settings = {"per_category": per_category, "resolution": resolution, "manifest_sha256": sha256_file(manifest)}
    name = "chamfer.json"
    if foreground is not None:
        settings["foreground"] = foreground_fingerprint(foreground)
        name = "chamfer-photos.json"
    out: dict[int, float] = {}
    for folder in sorted((Path(run) / STEPS_DIR).glob("*/model.json")):
        folder = folder.parent
        cached = folder / name
        meta = json.loads((folder / "model.json").read_text())
        weights = meta.get("weights_sha256")
        if cached.is_file():
            kept = json.loads(cached.read_text())
            if kept.get("settings") == settings and kept.get("weights_sha256") == weights:
                out[int(kept["step"])] = np.nan if kept[CHAMFER_TERM] is None else float(kept[CHAMFER_TERM])
                continue
        options = EvalOptions("val", resolution, per_category=per_category, photos=foreground is not None,
                              foreground=None if foreground is None else str(foreground))
        results = evaluate(str(folder), str(data), options)
        step = int(meta["steps"])
        value = results["chamfer_x1e3_category_mean"]        # None: every output was empty
        write_atomic(cached, json_text({"step": step, CHAMFER_TERM: value, "shapes": results["shapes"],
                                        "empty_outputs": results["empty_outputs"], "settings": settings,
                                        "weights_sha256": weights}).encode())
        out[step] = np.nan if value is None else float(value)
    return out


def foreground_fingerprint(foreground: str | Path) -> dict:
    """What decides a foreground network's masks: its weights (sha256 of the float32 tensors in key
    order, the same for a run and the checkpoint packaged from it) and its guided filter.
    ValueError if ``foreground`` is no foreground network's run or checkpoint folder."""


    saved = read_run(foreground)
    if saved.config.task != "foreground":
        raise ValueError(f"{foreground} is a {saved.config.task} model, not a foreground network")
    digest = hashlib.sha256()
    for key in sorted(saved.weights):
        digest.update(key.encode())
        digest.update(saved.weights[key].contiguous().numpy().tobytes())
    return {"weights_sha256": digest.hexdigest(), "mask_guide": saved.meta.get("mask_guide")}


def lowest_step(chamfer: dict[int, float]) -> int:
    """The step with the lowest finite figure, the earlier on a tie: the checkpoint chosen on the
    validation split.  ValueError when none is finite."""
    measured = [step for step, value in chamfer.items() if np.isfinite(value)]
    if not measured:
        raise ValueError("no kept step has a validation Chamfer distance (none kept, or every output empty)")
    return min(measured, key=lambda step: (chamfer[step], step))


def with_chamfer(curves: RunCurves, chamfer: dict[int, float]) -> RunCurves:
    """``curves`` with the validation term ``chamfer_x1e3`` (NaN at validated steps without a figure;
    ``curves`` itself when there is no figure)."""
    if not chamfer:
        return curves
    steps = curves.steps.get("val", np.array([], dtype=int))
    extra = sorted(set(chamfer) - set(int(s) for s in steps))
    if extra:
        raise ValueError(f"{curves.name}: weights kept at steps {extra} that its metrics.jsonl never validated")
    values = {split: dict(v) for split, v in curves.values.items()}
    values.setdefault("val", {})[CHAMFER_TERM] = np.array([chamfer.get(int(s), np.nan) for s in steps])
    return RunCurves(curves.name, {**curves.steps, "val": steps}, values, curves.seconds)


def moving_average(values: np.ndarray, window: int) -> np.ndarray:
    """Mean of each value and the ``window - 1`` before it (fewer at the start); NaNs skipped."""
    if window < 1:
        raise ValueError("window must be at least 1")
    ok = np.isfinite(values)
    total = np.concatenate([[0.0], np.cumsum(np.where(ok, values, 0.0))])
    count = np.concatenate([[0], np.cumsum(ok)])
    end = np.arange(1, len(values) + 1)
    start = np.maximum(end - window, 0)
    n = count[end] - count[start]
    return np.where(n > 0, (total[end] - total[start]) / np.maximum(n, 1), np.nan)


LOG_SPAN = 10.0
"""A panel whose positive values span more than this factor is drawn on a log scale."""


def log_scale(values: list[np.ndarray]) -> bool:
    """Whether a panel of these series reads better on a log scale: every finite value positive
    and the largest more than :data:`LOG_SPAN` times the smallest (runs of different tasks, say
    an autoencoder's Chamfer distance beside an image model's, would otherwise flatten all but
    the largest)."""
    finite = np.concatenate([np.asarray(v, float).ravel() for v in values] or [np.zeros(0)])
    finite = finite[np.isfinite(finite)]
    return bool(len(finite)) and finite.min() > 0 and finite.max() > LOG_SPAN * finite.min()


def plot(curves: list[RunCurves], out: str | Path, terms: list[str] | None = None, window: int = 50) -> list[str]:
    """Draw the curves to a PNG; returns the terms drawn (default: every term that some run
    validated, else trained, on; 'total' first)."""
    import matplotlib  # deferred: the train extra's; only drawing needs it
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    available = {t for c in curves for t in c.terms("val") or c.terms("train")}
    terms = terms or sorted(available, key=lambda t: (t != "total", t))
    missing = [t for t in terms if t not in available]
    if missing:
        raise ValueError(f"no run logged {', '.join(missing)}; logged: {', '.join(sorted(available))}")
    fig, axes = plt.subplots(1, len(terms), figsize=(4.2 * len(terms), 3.4), squeeze=False, sharex=True)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, term in zip(axes[0], terms):
        drawn = []
        for i, c in enumerate(curves):
            colour = colours[i % len(colours)]
            minutes = f", {c.seconds / 60:.0f} min" if c.seconds else ""
            last = max(int(s[-1]) for s in c.steps.values())
            if term in c.values.get("train", {}):
                drawn.append(moving_average(c.values["train"][term], window))
                ax.plot(c.steps["train"], drawn[-1], color=colour,
                        linewidth=1, alpha=0.6, label=f"{c.name} train ({last} steps{minutes})")
            if term in c.values.get("val", {}):
                drawn.append(c.values["val"][term])
                ax.plot(c.steps["val"], drawn[-1], color=colour, linewidth=2, marker="o",
                        markersize=3, label=f"{c.name} validation")
        log = log_scale(drawn)
        if log:
            ax.set_yscale("log")
        ax.set_title(term + (" (log scale)" if log else ""))
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(out) as tmp:             # a failed write leaves no half-written picture
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return terms


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.curves", __doc__, [
        "python -m research.curves runs/completion runs/completion-skips --out curves.png"])
    ap.add_argument("runs", nargs="+", help="run folders of python -m model.train")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--labels", nargs="+", default=None, help="a name per run (default: the folder names)")
    ap.add_argument("--terms", nargs="+", default=None, help="loss terms to draw (default: every validated one)")
    ap.add_argument("--window", type=int, default=50, help="training rows averaged per point (default 50)")
    ap.add_argument("--chamfer", default=None, metavar="DATA",
                    help="also measure the weights kept at each validated step on this dataset's validation split")
    ap.add_argument("--per-category", type=int, default=4,
                    help="with --chamfer: validation shapes per category (default 4)")
    ap.add_argument("--resolution", type=int, default=128,
                    help="with --chamfer: the patch sampling grid (default 128, research.evaluate's)")
    args = ap.parse_args(argv)
    try:
        if args.labels is not None and len(args.labels) != len(args.runs):
            raise ValueError(f"--labels gives {len(args.labels)} names for {len(args.runs)} runs")
        if args.window < 1:
            raise ValueError("--window must be at least 1")
        labels = args.labels or [None] * len(args.runs)
        if args.per_category < 1 or args.resolution < 2:
            raise ValueError("--per-category must be at least 1 and --resolution at least 2")
        curves = [read_curves(r, n) for r, n in zip(args.runs, labels)]
        if args.chamfer is not None:
            for i, run in enumerate(args.runs):
                chamfer = validation_chamfer(run, args.chamfer, args.per_category, args.resolution)
                curves[i] = with_chamfer(curves[i], chamfer)
                if chamfer:
                    measured = any(np.isfinite(v) for v in chamfer.values())
                    best = f"lowest at step {lowest_step(chamfer)}" if measured else "every output empty"
                    print(f"{curves[i].name}: validation Chamfer x10^3 " +
                          ", ".join(f"{k}: {v:.3f}" for k, v in sorted(chamfer.items())) + f"; {best}")
                else:
                    print(f"{curves[i].name}: no weights kept at validated steps ({run}/steps)")
        terms = plot(curves, args.out, args.terms, args.window)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {', '.join(terms)} of {len(curves)} run(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
