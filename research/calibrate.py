"""Decode-time calibration of an octree decoder's split decisions.

    python -m research.calibrate RUN --data DIR --out CALIBRATED_RUN [--split val]
    python -m research.calibrate COMPLETION_RUN --data DIR --keep-scan [--split val] [--per-category N]
    python -m research.calibrate FOREGROUND_RUN --data DIR --mask-guide [--split val]

A class-balanced structure loss makes the *split* class survive, at the price of predicting it
more often than it occurs where the network cannot tell *split* from *leaf* (the depth-5
decision on procedural shapes is close to chance).  Every extra split costs 8 children, so the
decoded trees grow.  This step picks, per adaptive depth, a bias added to the split logit so
that the teacher-forced number of predicted splits on the validation split equals the true
number, and writes a copy of the run with the bias folded into the prediction module's last
layer: evaluation, export and serving then need no extra setting.

``--mask-guide`` (foreground networks) chooses, on the validation split's photo-like views, the
guided filter their masks go through (:func:`calibrate_mask_guide`); export carries it into the
image bundle.

``--keep-scan`` (completion models) chooses, on the validation split, the bias towards *empty*
that the decoder uses when the output keeps the scan's own patches (:func:`calibrate_keep_scan`);
export carries it into the bundle, and the service and ``research.evaluate --keep-scan`` use it.
"""

from __future__ import annotations

import dataclasses
import shutil
import sys
from pathlib import Path

import numpy as np
import torch

from model.checkpoint import load_model
from model.cli import command_parser
from model.data.photos import photo_split_view
from model.files import atomic_path, json_text, write_atomic
from model.networks import OctreeDecoder
from model.networks.decoder import teacher_skips
from model.networks.foreground import torch_segment
from model.nn.tensors import OctreeTensors
from model.octree import SPLIT
from model.octree.metrics import Reference, mean_squared_distance, missing_part
from model.train.completion import truth_view
from model.train.config import KEEP_SCAN_FILE, MASK_GUIDE_FILE, load_checkpoint, write_weights
from model.train.tasks import TASKS, encode_with_guide

from .decoding import decoded_points
from .masks import mask_ious
from .measures import MISSING_GAP, split_subset
from .results import category_means
from .results_table import paired_difference

BIASES = np.round(np.arange(-4.0, 4.0001, 0.05), 2)


def split_logits(model, cfg, dataset, batch_size: int = 8) -> dict[int, tuple[np.ndarray, np.ndarray]]:
    """Teacher-forced status logits and true labels per 3-class depth, over a whole split."""
    dec: OctreeDecoder = model.decoder
    out: dict[int, list] = {}
    with torch.no_grad():
        for s in range(0, len(dataset), batch_size):
            idx = np.arange(s, min(len(dataset), s + batch_size))
            octree, _ = dataset.batch(idx)
            tensors = OctreeTensors.from_octree(octree)
            latent, guide = encode_with_guide(model, cfg, dataset, idx)
            for (logits, _), d in zip(dec(latent, tensors, teacher_skips(guide, octree)),
                                      range(dec.full_depth, dec.depth + 1)):
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
    """Write the calibrated copy of ``run`` to ``out`` (a run folder's as a run folder, a checkpoint
    folder's, such as a step a run kept, as a checkpoint folder); returns the per-depth report."""
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
    if not (Path(run) / "checkpoint.pt").is_file():           # a checkpoint folder
        meta = {k: v for k, v in loaded.meta.items() if not k.startswith("weights") and k != "parameters"}
        write_weights(out_dir, model.state_dict(), {**meta, "calibration": report})
        write_atomic(out_dir / "calibration.json", json_text(report).encode())
        return report
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


KEEP_SCAN_STARTS = (4, 5, 6)
KEEP_SCAN_BIASES = (0.5, 1.0, 1.5, 2.0, 2.5, 3.0)


def keep_scan_candidates(depth: int) -> list[dict[int, float]]:
    """No bias, then each bias from each start depth down to ``depth``."""
    return [{}] + [{d: b for d in range(start, depth + 1)} for start in KEEP_SCAN_STARTS if start <= depth
                   for b in KEEP_SCAN_BIASES]


def calibrate_keep_scan(run: str, data: str, split: str = "val", batch_size: int = 8, seed: int = 0,
                        limit: int | None = None, resolution: int = 128, draws: int = 10_000,
                        per_category: int | None = None) -> dict:
    """Choose the empty-class bias a completion decodes with when its output keeps the scan, on
    ``split``, and record it with the run (model.json's ``keep_scan`` of a checkpoint folder, else
    keep_scan.json of the run folder).

    Fused with its scan, the network's output only counts where the scan has no points, so the
    octants it is unsure of there may cost more than they add: a bias towards *empty* at the finer
    depths trades some of the missing part for fewer surfaces the shape does not have.  The
    choice: among the settings whose fused outputs' Chamfer distance (category mean) is not
    significantly above the lowest's (its paired 95% bootstrap interval over the shapes,
    ``draws`` draws, reaches 0), the one closest to the missing part (the completion's own
    measure, :data:`research.measures.MISSING_GAP`).  ``limit``: the first shapes of the
    split only; ``per_category``: of those, the first so many of each category (a subset every
    category is in: each candidate decodes every shape, which at depth 7 costs hours on the whole
    split); ``resolution``: the patch sampling grid."""
    loaded = load_model(run)
    model, cfg = loaded.model, loaded.config
    if cfg.task != "completion" or not isinstance(model.decoder, OctreeDecoder):
        raise ValueError("--keep-scan calibrates an octree completion model")
    cfg.data = data
    task = TASKS[cfg.task]
    dataset = task.dataset(cfg, split, seed, points=20_000, limit=limit)
    chosen = split_subset(data, split, cfg.categories, limit, len(dataset), per_category)
    candidates = keep_scan_candidates(cfg.depth)
    rows: list[list[dict]] = [[] for _ in candidates]
    floor: dict[str, list[float]] = {}
    for s in range(0, len(chosen), batch_size):
        idx = chosen[s:s + batch_size]
        with torch.no_grad():
            latent, guide = encode_with_guide(model, cfg, dataset, idx)
        scans = [dataset.scan(i) for i in idx]
        truths = {i: Reference(dataset.samples[i].points) for i in idx}      # measured against every candidate
        parts = {i: missing_part(dataset.samples[i].points, dataset.samples[i].partial, MISSING_GAP) for i in idx}
        for i in idx:
            sample = dataset.samples[i]
            floor.setdefault(sample.category, []).append(truths[i].chamfer(sample.partial) * 1e3)
        for c, bias in enumerate(candidates):
            for i, (pts, _) in zip(idx, decoded_points(model, latent, None, resolution, seed, scans=scans, empty_bias=bias,
                                                   guide=guide)):
                sample = dataset.samples[i]
                pts = truth_view(sample, pts)
                found = len(pts) > 0
                rows[c].append({"category": sample.category, "shape_id": sample.shape_id,
                                "chamfer_x1e3": truths[i].chamfer(pts) * 1e3 if found else None,
                                "missing_x1e3": mean_squared_distance(parts[i], pts) * 1e3
                                if found and len(parts[i]) else None})
    best, tied = choose_keep_scan(rows, draws)
    chamfer = [category_mean(r, "chamfer_x1e3") for r in rows]
    missing = [category_mean(r, "missing_x1e3") for r in rows]
    report = {"empty_bias": {str(d): b for d, b in candidates[best].items()}, "split": split, "resolution": resolution,
              "shapes": len(chosen), "per_category": per_category, "chamfer_x1e3_category_mean": round(chamfer[best], 4),
              "missing_x1e3_category_mean": round(missing[best], 4),
              "scan_chamfer_x1e3_category_mean": round(float(np.mean([np.mean(v) for v in floor.values()])), 4),
              "rule": "the least missing-part distance among the settings whose Chamfer is not significantly "
                      "above the lowest's (paired 95% bootstrap)",
              "candidates": [{"empty_bias": {str(d): b for d, b in c.items()}, "chamfer_x1e3_category_mean": round(m, 4),
                              "missing_x1e3_category_mean": round(x, 4), "tied_with_lowest": i in tied}
                             for i, (c, m, x) in enumerate(zip(candidates, chamfer, missing))]}
    record_with_run(run, loaded.meta, "keep_scan", KEEP_SCAN_FILE, report)
    return report


def choose_keep_scan(rows: list[list[dict]], draws: int = 10_000) -> tuple[int, list[int]]:
    """The chosen setting of :func:`calibrate_keep_scan` and the settings tied with the lowest
    Chamfer: ``rows[c]`` holds setting c's per-shape rows (category, shape_id, chamfer_x1e3,
    missing_x1e3; the same shapes for every setting)."""
    chamfer = [category_mean(r, "chamfer_x1e3") for r in rows]
    missing = [category_mean(r, "missing_x1e3") for r in rows]
    lowest = int(np.argmin(chamfer))
    tied = [c for c in range(len(rows))
            if c == lowest or paired_difference({"per_shape": rows[lowest]}, {"per_shape": rows[c]}, draws).low <= 0]
    return min(tied, key=lambda c: (np.nan_to_num(missing[c], nan=np.inf), chamfer[c])), tied


def category_mean(rows: list[dict], metric: str) -> float:
    """The mean over categories of the mean ``metric`` of the ``rows`` that have one (NaN: none)."""
    kept = [r for r in rows if r[metric] is not None]
    if not kept:
        return float("nan")
    return float(np.mean(list(category_means([r["category"] for r in kept], [r[metric] for r in kept]).values())))


def record_with_run(run: str, meta: dict, key: str, filename: str, report: dict) -> None:
    """Keep a calibration ``report`` with the run it was made for: as ``key`` of a checkpoint
    folder's model.json (``meta`` is that file's content), else as ``filename`` in the run folder
    (read back into the run's provenance by :func:`model.train.config.read_run`)."""
    path = Path(run)
    if (path / "model.json").is_file():
        write_atomic(path / "model.json", json_text({**meta, key: report}).encode())
    else:
        write_atomic(path / filename, json_text(report).encode())


MASK_GUIDE_RADII = (0.0, 1.0, 2.0, 3.0, 4.0)
"""Guided-filter radii tried by ``--mask-guide``, in the foreground network's pixels (0: none); whole
pixels, since the filter's windows are on the network's grid (:func:`model.image.mask.to_image`)."""
MASK_GUIDE_EPS = (1e-5, 3e-5, 1e-4, 3e-4)
"""Guided-filter regularisers tried by ``--mask-guide`` (the guide is the grey image in [0, 1])."""


def calibrate_mask_guide(run: str, data: str, split: str = "val", limit: int | None = None) -> dict:
    """Choose the guided filter of a foreground network's masks (:class:`model.image.mask.MaskSpec`
    ``guide``, ``guide_eps``) by the category-mean mask IoU of the split's photo-like views through
    the service's path, and record it with the run (model.json's ``mask_guide`` of a checkpoint
    folder, else mask_guide.json of the run folder).  The network runs in torch, once per distinct
    image (looks repeat across candidates)."""


    loaded = load_model(run)
    cfg = loaded.config
    if cfg.task != "foreground":
        raise ValueError(f"--mask-guide calibrates a foreground network, not a {cfg.task} model")
    cfg.data = data
    records = TASKS[cfg.task].dataset(cfg, split, 0, limit=limit)
    photos = [photo_split_view(s.images, s.shape_id) for s in records.samples]
    base = dataclasses.replace(TASKS[cfg.task].spec(cfg), guide=0.0)
    network, seen = torch_segment(loaded.model.net, base), {}

    def segment(rgb: np.ndarray) -> np.ndarray:
        key = (rgb.shape, hash(rgb.tobytes()))
        if key not in seen:
            seen[key] = network(rgb)
        return seen[key]

    candidates = [(0.0, MASK_GUIDE_EPS[0])] + [(r, e) for r in MASK_GUIDE_RADII if r > 0 for e in MASK_GUIDE_EPS]
    categories = [s.category for s in records.samples]
    means = []
    for radius, eps in candidates:
        ious = mask_ious(photos, segment, dataclasses.replace(base, guide=radius, guide_eps=eps))
        means.append(float(np.mean(list(category_means(categories, ious).values()))))
    best = int(np.argmax(means))
    radius, eps = candidates[best]
    report = {"radius": radius, "eps": eps, "split": split, "photos": len(photos),
              "mask_iou_category_mean": round(means[best], 4),
              "candidates": [{"radius": r, "eps": e, "mask_iou_category_mean": round(m, 4)}
                             for (r, e), m in zip(candidates, means)]}
    record_with_run(run, loaded.meta, "mask_guide", MASK_GUIDE_FILE, report)
    return report


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.calibrate", __doc__, [
        "python -m research.calibrate runs/img --data data/procedural --out runs/img-cal"])
    ap.add_argument("run", help="run folder or checkpoint folder (such as RUN/steps/<step>) of an aocnn decoder "
                    "(autoencoder, image or completion model); with --mask-guide of a foreground network")
    ap.add_argument("--data", required=True, help="dataset folder the run was trained on")
    ap.add_argument("--out", default=None, help="folder for the calibrated copy of the run (split biases)")
    ap.add_argument("--split", default="val", choices=("train", "val"), help="split to calibrate on (default val)")
    ap.add_argument("--keep-scan", action="store_true",
                    help="completion: instead of the split biases, choose the empty-class bias for outputs that "
                         "keep the scan and record it with the run (model.json or keep_scan.json)")
    ap.add_argument("--mask-guide", action="store_true",
                    help="foreground network: choose the guided filter of its masks and record it with the run "
                         "(model.json or mask_guide.json)")
    ap.add_argument("--limit", type=int, default=None,
                    help="--keep-scan, --mask-guide: the first N shapes of the split only")
    ap.add_argument("--per-category", type=int, default=None,
                    help="--keep-scan: only the first N shapes of each category (a smaller subset every category is in)")
    ap.add_argument("--resolution", type=int, default=128,
                    help="--keep-scan: patch sampling grid, a power of two (default 128, the paper's)")
    args = ap.parse_args(argv)
    try:
        if args.limit is not None and args.limit < 1:
            raise ValueError("--limit must be at least 1")
        if args.per_category is not None and (not args.keep_scan or args.per_category < 1):
            raise ValueError("--per-category takes a number of shapes >= 1 and goes with --keep-scan")
        if args.keep_scan and args.mask_guide:
            raise ValueError("give one of --keep-scan and --mask-guide")
        if args.mask_guide:
            report = calibrate_mask_guide(args.run, args.data, args.split, limit=args.limit)
        elif args.keep_scan:
            report = calibrate_keep_scan(args.run, args.data, args.split, limit=args.limit,
                                         resolution=args.resolution, per_category=args.per_category)
        elif args.out is None:
            raise ValueError("--out is required (or --keep-scan)")
        else:
            report = calibrate(args.run, args.data, args.out, args.split)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.mask_guide:
        none = report["candidates"][0]["mask_iou_category_mean"]
        print(f"{args.run}: guided filter radius {report['radius']:g}, eps {report['eps']:g}: mask IoU "
              f"{report['mask_iou_category_mean']:.4f} on {report['photos']} {report['split']} photos (none: {none:.4f})")
        return 0
    if args.keep_scan:
        bias = ", ".join(f"depth {d} {b:+.1f}" for d, b in report["empty_bias"].items()) or "none"
        none = report["candidates"][0]
        print(f"{args.run}: keep_scan empty bias {bias}: Chamfer x1e3 {report['chamfer_x1e3_category_mean']:.3f}, "
              f"missing part {report['missing_x1e3_category_mean']:.3f} on {report['shapes']} {report['split']} "
              f"shapes (the scans themselves {report['scan_chamfer_x1e3_category_mean']:.3f}; no bias "
              f"{none['chamfer_x1e3_category_mean']:.3f}, {none['missing_x1e3_category_mean']:.3f})")
        return 0
    for d, row in report["depths"].items():
        print(f"depth {d}: split bias {row['bias']:+.2f}, predicted/true splits "
              f"{row['uncalibrated_predicted_over_true']:.2f} -> {row['predicted_over_true']:.2f}, "
              f"recall {row['recall']:.3f}, precision {row['precision']:.3f}")
    print(f"{args.out}: calibrated copy of {args.run}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
