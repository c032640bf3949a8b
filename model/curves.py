"""Training curves of runs: per loss term, the training loss (moving average) and the validation
loss against the step, one panel per term, every run in its own colour.

    python -m model.curves RUN [RUN ...] --out PNG [--labels NAME ...] [--terms total ...] [--window 50]

Reads each run folder's ``metrics.jsonl`` (written by ``python -m model.train``: a row per logged
training step and per validation).  A run that was interrupted and resumed logs some steps twice;
the last row of each (split, step) counts.  The legend gives each run's last step and its
training time.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .cli import command_parser
from .files import atomic_path

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


def plot(curves: list[RunCurves], out: str | Path, terms: list[str] | None = None, window: int = 50) -> list[str]:
    """Draw the curves to a PNG; returns the terms drawn (default: every term that some run
    validated, else trained, on; 'total' first)."""
    import matplotlib
    matplotlib.use("Agg")
    from matplotlib import pyplot as plt

    available = {t for c in curves for t in c.terms("val") or c.terms("train")}
    terms = terms or sorted(available, key=lambda t: (t != "total", t))
    missing = [t for t in terms if t not in available]
    if missing:
        raise ValueError(f"no run logged {', '.join(missing)}; logged: {', '.join(sorted(available))}")
    fig, axes = plt.subplots(1, len(terms), figsize=(4.2 * len(terms), 3.4), squeeze=False)
    colours = plt.rcParams["axes.prop_cycle"].by_key()["color"]
    for ax, term in zip(axes[0], terms):
        for i, c in enumerate(curves):
            colour = colours[i % len(colours)]
            minutes = f", {c.seconds / 60:.0f} min" if c.seconds else ""
            last = max(int(s[-1]) for s in c.steps.values())
            if term in c.values.get("train", {}):
                ax.plot(c.steps["train"], moving_average(c.values["train"][term], window), color=colour,
                        linewidth=1, alpha=0.6, label=f"{c.name} train ({last} steps{minutes})")
            if term in c.values.get("val", {}):
                ax.plot(c.steps["val"], c.values["val"][term], color=colour, linewidth=2, marker="o",
                        markersize=3, label=f"{c.name} validation")
        ax.set_title(term)
        ax.set_xlabel("step")
        ax.grid(alpha=0.3)
    axes[0][0].legend(fontsize=7)
    fig.tight_layout()
    with atomic_path(out) as tmp:             # a failed write leaves no half-written picture
        fig.savefig(tmp, dpi=110, format="png")
    plt.close(fig)
    return terms


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m model.curves", __doc__, [
        "python -m model.curves runs/completion runs/completion-skips --out curves.png"])
    ap.add_argument("runs", nargs="+", help="run folders of python -m model.train")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--labels", nargs="+", default=None, help="a name per run (default: the folder names)")
    ap.add_argument("--terms", nargs="+", default=None, help="loss terms to draw (default: every validated one)")
    ap.add_argument("--window", type=int, default=50, help="training rows averaged per point (default 50)")
    args = ap.parse_args(argv)
    try:
        if args.labels is not None and len(args.labels) != len(args.runs):
            raise ValueError(f"--labels gives {len(args.labels)} names for {len(args.runs)} runs")
        if args.window < 1:
            raise ValueError("--window must be at least 1")
        labels = args.labels or [None] * len(args.runs)
        curves = [read_curves(r, n) for r, n in zip(args.runs, labels)]
        terms = plot(curves, args.out, args.terms, args.window)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {', '.join(terms)} of {len(curves)} run(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
