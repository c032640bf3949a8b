"""Choose a run's checkpoint on the validation split: of the weights it kept at its validated
steps (``RUN/steps/<step>/``), the step with the lowest validation Chamfer distance, copied to a
checkpoint folder that every command taking a run reads (``--teacher``, ``--init``,
``research.calibrate``, ``research.evaluate``, ``research.release --run``).

    python -m research.choose RUN --data DATA --out FOLDER [--per-category 4] [--resolution 128] [--photos FG]

The figures are :func:`research.curves.validation_chamfer`'s (measured once, kept beside each step's
weights).  ``--photos FG`` (image models): measured as served on the validation shapes' photo-like
views, their backgrounds removed by the foreground network FG, for a model trained for photographs.
Ties go to the earlier step.  ``FOLDER/model.json`` is the step's own, with ``chosen`` added: the
rule, the settings and every step's figure.  Rerunning picks up steps kept since.
"""

from __future__ import annotations

import json
import shutil
import sys
from dataclasses import dataclass
from pathlib import Path

from model.cli import command_parser
from model.files import atomic_path, json_text, write_atomic
from model.train.config import STEPS_DIR

from .curves import lowest_step, validation_chamfer


@dataclass(frozen=True)
class Choice:
    """The chosen step and the validation Chamfer (x 10^3) of every kept step (NaN: every output empty)."""

    step: int
    chamfer: dict[int, float]


def choose(run: str | Path, data: str | Path, out: str | Path, per_category: int = 4,
           resolution: int = 128, foreground: str | Path | None = None) -> Choice:
    """Measure ``run``'s kept steps on ``data``'s validation split (with ``foreground``: on its
    photo-like views, as :func:`research.curves.validation_chamfer`) and copy the best to ``out``
    (weights first, then ``model.json``: a folder without ``model.json`` is no checkpoint)."""

    run, out = Path(run), Path(out)
    if not (run / STEPS_DIR).is_dir():
        raise ValueError(f"{run}: no {STEPS_DIR}/ folder (a run of python -m model.train that validated)")
    if out.resolve() == run.resolve() or run.resolve() in out.resolve().parents:
        raise ValueError(f"--out {out} is inside the run {run}; give a folder of its own")
    chamfer = validation_chamfer(run, data, per_category, resolution, foreground)
    step = lowest_step(chamfer)
    source = run / STEPS_DIR / f"{step:06d}"
    meta = json.loads((source / "model.json").read_text())
    views = "clean renders" if foreground is None else "photo-like views as served (the foreground network's masks)"
    meta["chosen"] = {"rule": "lowest validation Chamfer distance (x 10^3, category mean) of the kept steps, "
                              f"on {views}",
                      "run": str(run.resolve()), "data": str(Path(data).resolve()),
                      "foreground": None if foreground is None else str(Path(foreground).resolve()),
                      "per_category": per_category, "resolution": resolution,
                      "chamfer_x1e3": {str(k): v for k, v in sorted(chamfer.items())}}
    out.mkdir(parents=True, exist_ok=True)
    (out / "model.json").unlink(missing_ok=True)
    with atomic_path(out / "model.pt") as tmp:
        shutil.copyfile(source / "model.pt", tmp)
    write_atomic(out / "model.json", json_text(meta).encode())
    return Choice(step, chamfer)


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.choose", __doc__, [
        "python -m research.choose runs/ae7 --data data/procedural7 --out runs/ae7-best"])
    ap.add_argument("run", help="a run folder of python -m model.train (its steps/ are the candidates)")
    ap.add_argument("--data", required=True, help="the dataset whose validation split decides")
    ap.add_argument("--out", required=True, help="checkpoint folder to write (model.pt + model.json)")
    ap.add_argument("--per-category", type=int, default=4, help="validation shapes per category (default 4)")
    ap.add_argument("--resolution", type=int, default=128, help="the patch sampling grid (default 128)")
    ap.add_argument("--photos", metavar="FG", default=None,
                    help="image models: measure on the validation shapes' photo-like views as served, their "
                         "backgrounds removed by this foreground network (checkpoint or run folder)")
    args = ap.parse_args(argv)
    try:
        if args.per_category < 1 or args.resolution < 2:
            raise ValueError("--per-category must be at least 1 and --resolution at least 2")
        choice = choose(args.run, args.data, args.out, args.per_category, args.resolution, args.photos)
    except (ValueError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    figures = ", ".join(f"{k}: {v:.3f}" for k, v in sorted(choice.chamfer.items()))
    views = "" if args.photos is None else " on photos"
    print(f"{args.out}: step {choice.step} of {args.run} (validation Chamfer x10^3{views} {figures})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
