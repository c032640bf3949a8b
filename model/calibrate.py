"""Decode-time calibration of an octree decoder's split decisions.

    python -m model.calibrate RUN --data DIR --out CALIBRATED_RUN [--split val]

A class-balanced structure loss makes the *split* class survive, at the price of predicting it
more often than it occurs where the network cannot tell *split* from *leaf* (the depth-5
decision on procedural shapes is close to chance).  Every extra split costs 8 children, so the
decoded trees grow.  This step picks, per adaptive depth, a bias added to the split logit so
that the teacher-forced number of predicted splits on the validation split equals the true
number, and writes a copy of the run with the bias folded into the prediction module's last
layer: evaluation, export and serving then need no extra setting.
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np
import torch

from .files import atomic_path, json_text, write_atomic
from .networks import OctreeDecoder
from .nn.tensors import OctreeTensors
from .octree import SPLIT
from .checkpoint import load_model
from .train.config import load_checkpoint
from .train.tasks import TASKS
from .cli import command_parser

BIASES = np.round(np.arange(-4.0, 4.0001, 0.05), 2)


def split_logits(model, cfg, dataset, batch_size: int = 8) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Teacher-forced status logits and true labels per 3-class depth, over a whole split."""
    dec: OctreeDecoder = model.decoder
    out: dict[int, list] = {}
    task = TASKS[cfg.task]
    with torch.no_grad():
        for s in range(0, len(dataset), batch_size):
            idx = np.arange(s, min(len(dataset), s + batch_size))
            octree, _ = dataset.batch(idx)
            tensors = OctreeTensors.from_octree(octree)
            latent = task.encode(model, cfg, dataset, idx)
            for (logits, _), d in zip(dec(latent, tensors), range(dec.full_depth, dec.depth + 1)):
                if dec.classes(d) == 3 and d < dec.depth:
                    out.setdefault(d, []).append((logits.numpy(), tensors.levels[d].label.numpy()))
    return {d: (np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts]))
            for d, parts in out.items()}


def matching_bias(logits: np.ndarray, labels: np.ndarray) -> tuple[float, dict]:
    """The split-logit bias whose predicted split count is closest to the true count, and the
    recall / precision / count ratio it gives."""
    true = max(1, int((labels == SPLIT).sum()))
    best = None
    for b in BIASES:
        z = logits.copy()
        z[:, SPLIT] += b
        pred = z.argmax(1) == SPLIT
        ratio = pred.sum() / true
        if best is None or abs(ratio - 1) < abs(best[1] - 1):
            tp = int((pred & (labels == SPLIT)).sum())
            best = (float(b), float(ratio), tp / true, tp / max(1, int(pred.sum())))
    b, ratio, recall, precision = best
    return b, {"bias": b, "predicted_over_true": round(ratio, 4), "recall": round(recall, 4),
               "precision": round(precision, 4)}


def fold_bias(decoder: OctreeDecoder, depth: int, bias: float) -> None:
    """Add ``bias`` to the split logit of ``depth`` in the prediction module's last layer."""
    last = decoder.pred[str(depth)][-1]
    with torch.no_grad():
        last.bias[SPLIT] += bias


def calibrate(run: str, data: str, out: str, split: str = "val") -> dict:
    """Write the calibrated copy of ``run`` to ``out``; returns the per-depth report."""
    loaded = load_model(run)
    model, cfg = loaded.model, loaded.config
    if not isinstance(model.decoder, OctreeDecoder) or model.decoder.mode != "adaptive":
        raise ValueError("calibration needs an Adaptive O-CNN (aocnn) decoder")
    out_dir = Path(out)
    if out_dir.resolve() == Path(run).resolve():
        raise ValueError("--out must differ from RUN: the run's own checkpoint is kept")
    cfg.data = data
    dataset = TASKS[cfg.task].dataset(cfg, split, cfg.seed + 1)
    report = {"split": split, "shapes": len(dataset), "depths": {}}
    for d, (logits, labels) in sorted(split_logits(model, cfg, dataset).items()):
        b, row = matching_bias(logits, labels)
        z0 = logits.argmax(1) == SPLIT
        row["uncalibrated_predicted_over_true"] = round(float(z0.sum() / max(1, (labels == SPLIT).sum())), 4)
        report["depths"][str(d)] = row
        fold_bias(model.decoder, d, b)
    state = load_checkpoint(Path(run) / "checkpoint.pt")
    state["model"] = model.state_dict()
    state["calibration"] = report
    out_dir.mkdir(parents=True, exist_ok=True)
    with atomic_path(out_dir / "checkpoint.pt") as tmp:
        torch.save(state, tmp)
    for name in ("config.json", "metrics.jsonl"):
        if (Path(run) / name).is_file():
            shutil.copyfile(Path(run) / name, out_dir / name)
    write_atomic(out_dir / "calibration.json", json_text(report).encode())
    return report


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m model.calibrate", __doc__, [
        "python -m model.calibrate runs/img --data data/procedural --out runs/img-cal"])
    ap.add_argument("run", help="run folder of an aocnn decoder (autoencoder or image model)")
    ap.add_argument("--data", required=True, help="dataset folder the run was trained on")
    ap.add_argument("--out", required=True, help="folder for the calibrated copy of the run")
    ap.add_argument("--split", default="val", choices=("train", "val"), help="split to calibrate on (default val)")
    args = ap.parse_args(argv)
    try:
        report = calibrate(args.run, args.data, args.out, args.split)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    for d, row in report["depths"].items():
        print(f"depth {d}: split bias {row['bias']:+.2f}, predicted/true splits "
              f"{row['uncalibrated_predicted_over_true']:.2f} -> {row['predicted_over_true']:.2f}, "
              f"recall {row['recall']:.3f}, precision {row['precision']:.3f}")
    print(f"{args.out}: calibrated copy of {args.run}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
