"""How shape completion degrades with the scan: fewer views, more and larger holes, more noise.

    python -m research.degrade RUN [RUN ...] --data DIR --out results.json [--limit-per-category N] [--split test]

New partial scans are cut from the test shapes' complete virtual scans (rebuilt exactly as the
dataset build made them) under each setting of :data:`SETTINGS`, with the same random stream per
shape in every setting and for every run, so rows and runs are paired.  Each scan is built into
its octree by the service's code (:func:`model.octree.scan_octree`, the scanner's normals), the
shape completed, and the output compared with the complete truth by the Chamfer distance (x10^3,
the complete shape's cube, category mean) and by the missing part's distance to it
(:func:`model.octree.metrics.missing_distance`), each beside the partial input's own value.
"""

from __future__ import annotations

import json
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from model.checkpoint import load_model
from model.cli import command_parser
from model.data.dataset import BuildConfig, ShapeTask, load_record, scan_shape
from model.data.partial import partial_from_scan
from model.data.shapes import stable_hash
from model.files import json_text, write_atomic
from model.octree import scan_frame, scan_octree, validate
from model.octree.batch import merge_octrees
from model.octree.metrics import chamfer_distance, mean_squared_distance, missing_part
from model.octree.pointcloud import MIN_SCAN_POINTS, normalization_of

from .decoding import decoded_points
from .measures import MISSING_GAP
from .results_table import paired_difference

MIN_POINTS = MIN_SCAN_POINTS
"""Scans with fewer points are not completed (the service's own minimum); such shapes are left
out of every row of that setting and counted."""


@dataclass(frozen=True)
class PartialSettings:
    """One way of cutting partial scans (ranges inclusive; radii and noise as fractions of the
    bounding-sphere diameter), as :func:`model.data.partial.partial_from_scan` takes them."""

    name: str
    views: tuple[int, int] = (3, 5)
    holes: tuple[int, int] = (1, 3)
    radius: tuple[float, float] = (0.05, 0.15)
    noise: float = 0.005


SETTINGS = (
    PartialSettings("as trained (3-5 views, 1-3 holes, noise 0.005)"),
    PartialSettings("2 views", views=(2, 2)),
    PartialSettings("1 view", views=(1, 1)),
    PartialSettings("3-5 large holes per view", holes=(3, 5), radius=(0.15, 0.25)),
    PartialSettings("noise 0.01", noise=0.01),
    PartialSettings("noise 0.02", noise=0.02),
)


def _tasks(data: Path, limit_per_category: int | None, split: str = "test") -> tuple[list[ShapeTask], BuildConfig]:
    manifest = json.loads((data / "manifest.json").read_text())
    cfg = BuildConfig(**manifest["config"])
    first = next((r for r in manifest["records"] if r["split"] == split), None)
    if first is not None and str(load_record(data / first["path"])["source"]) != "procedural":
        raise ValueError(f"{data}: degradation needs a procedural dataset (its meshes are regenerated)")
    tasks, seen = [], {}
    for row in manifest["records"]:
        if row["split"] != split:
            continue
        seen[row["category"]] = seen.get(row["category"], 0) + 1
        if limit_per_category is not None and seen[row["category"]] > limit_per_category:
            continue
        index = int(row["shape_id"].rsplit("_", 1)[1])
        tasks.append(ShapeTask("procedural", row["category"], row["shape_id"], split, index=index))
    if not tasks:
        raise ValueError(f"{data} has no {split} shapes")
    return tasks, cfg


def degrade(runs: list[str], data: str, limit_per_category: int | None = None, resolution: int = 128,
            split: str = "test") -> dict:
    """Per setting and run: per-shape Chamfer distances, category means and paired differences."""
    models = [load_model(r) for r in runs]
    for m in models:
        if m.config.task != "completion":
            raise ValueError(f"{m.meta.get('source_run', 'a model')} is not a completion model")
    tasks, cfg = _tasks(Path(data), limit_per_category, split)
    rows = {s.name: {r: [] for r in ["input", *runs]} for s in SETTINGS}
    t = time.perf_counter()
    for task in tasks:
        _, _, scan, _ = scan_shape(task, cfg)
        truth = normalization_of(scan.points)
        truth_pts = truth.to_cube(scan.points)
        for s in SETTINGS:
            rng = np.random.default_rng(stable_hash("degrade", task.shape_id))
            pts, nrm, _ = partial_from_scan(scan, rng, s.views, s.holes, s.radius, s.noise)
            base = {"category": task.category, "shape_id": task.shape_id, "points": int(len(pts))}
            if len(pts) < MIN_POINTS:         # the holes took (almost) everything: nothing to complete
                for name in rows[s.name]:
                    rows[s.name][name].append({**base, "chamfer_x1e3": None, "missing_x1e3": None})
                continue
            frame = scan_frame(pts.astype(np.float64))
            seen = truth.to_cube(pts)
            missing = missing_part(truth_pts, seen, MISSING_GAP)          # once per scan, for every row
            rows[s.name]["input"].append({**base, "chamfer_x1e3": chamfer_distance(truth_pts, seen) * 1e3,
                                          "missing_x1e3": _missing_x1e3(missing, seen)})
            cloud = validate(pts, nrm)
            for run, m in zip(runs, models):
                tree = scan_octree(cloud, m.config.depth, adaptive=m.model.arch.octree == "adaptive")
                with torch.no_grad():
                    latent, guide = m.model.encode_octree(merge_octrees([tree]))
                out, _ = decoded_points(m.model, latent, None, resolution, 0, guide=guide)[0]
                out = truth.to_cube(frame.to_world(out)) if len(out) else out
                rows[s.name][run].append({**base, **(
                    {"chamfer_x1e3": chamfer_distance(truth_pts, out) * 1e3, "missing_x1e3": _missing_x1e3(missing, out)}
                    if len(out) else {"chamfer_x1e3": None, "missing_x1e3": None})})
    table = {}
    for s in SETTINGS:
        entry = {"settings": asdict(s), "rows": {}}
        for name, per_shape in rows[s.name].items():
            res = {"per_shape": per_shape, "too_few_points": sum(r["points"] < MIN_POINTS for r in per_shape),
                   "empty_outputs": sum(r["chamfer_x1e3"] is None and r["points"] >= MIN_POINTS for r in per_shape)}
            for metric in ("chamfer_x1e3", "missing_x1e3"):
                res[f"{metric}_category_mean"] = _category_mean(per_shape, metric)
                res[f"{metric}_minus_input"] = None
                if name != "input" and res[f"{metric}_category_mean"] is not None:
                    d = paired_difference({"per_shape": rows[s.name]["input"]}, {"per_shape": per_shape}, metric=metric)
                    res[f"{metric}_minus_input"] = asdict(d)
            entry["rows"][name] = res
        table[s.name] = entry
    return {"runs": runs, "data": str(data), "split": split, "shapes": len(tasks), "resolution": resolution,
            "settings": table, "seconds": time.perf_counter() - t}


def _missing_x1e3(missing: np.ndarray, points: np.ndarray) -> float | None:
    """The missing part's mean squared distance to ``points`` x1e3 (None when nothing is missing)."""
    return mean_squared_distance(missing, points) * 1e3 if len(missing) else None


def _category_mean(rows: list[dict], metric: str) -> float | None:
    by_cat: dict[str, list[float]] = {}
    for r in rows:
        if r.get(metric) is not None:
            by_cat.setdefault(r["category"], []).append(r[metric])
    return float(np.mean([np.mean(v) for v in by_cat.values()])) if by_cat else None


def markdown(results: dict, labels: list[str]) -> str:
    """Per metric, one line per setting: the input's value and each run's, with its paired
    difference from the input (negative: the model improves on the scan)."""
    lines = []
    for metric, title in (("chamfer_x1e3", "Chamfer x1e3 to the complete truth"),
                          ("missing_x1e3", "missing part: mean squared distance x1e3 to the output")):
        lines += [f"\n{title} (category mean; run - input with 95% bootstrap interval)\n",
                  "| scan | input itself | " + " | ".join(labels) + " |", "|---|---|" + "---|" * len(labels)]
        for name, entry in results["settings"].items():
            value = entry["rows"]["input"][f"{metric}_category_mean"]
            cells = ["—" if value is None else f"{value:.3f}"]
            for run in results["runs"]:
                r = entry["rows"][run]
                d = r[f"{metric}_minus_input"]
                cell = "— (no output)" if d is None else (f"{r[f'{metric}_category_mean']:.3f} "
                                                         f"({d['mean']:+.3f} [{d['low']:+.3f}, {d['high']:+.3f}])")
                cells.append(cell + (f", {r['empty_outputs']} empty" if r["empty_outputs"] else ""))
            small = entry["rows"]["input"]["too_few_points"]
            label = name + (f" ({small} scans under {MIN_POINTS} points left out)" if small else "")
            lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.degrade", __doc__, [
        "python -m research.degrade runs/complete runs/complete-ocnn --data data/procedural --out degrade.json"])
    ap.add_argument("runs", nargs="+", help="completion run or checkpoint folders")
    ap.add_argument("--data", required=True, help="the procedural dataset the runs were trained on")
    ap.add_argument("--out", required=True, help="results JSON")
    ap.add_argument("--limit-per-category", type=int, default=None, help="test shapes per category (default all)")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"), help="split (default test)")
    ap.add_argument("--labels", nargs="+", default=None, help="names of the runs in the table (default: folder names)")
    args = ap.parse_args(argv)
    try:
        if args.labels and len(args.labels) != len(args.runs):
            raise ValueError("give one --labels entry per run")
        if args.limit_per_category is not None and args.limit_per_category < 1:
            raise ValueError("--limit-per-category must be at least 1")
        if not (Path(args.data) / "manifest.json").is_file():
            raise FileNotFoundError(f"{args.data}/manifest.json not found")
        results = degrade(args.runs, args.data, args.limit_per_category, split=args.split)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    write_atomic(args.out, json_text(results).encode())
    print(markdown(results, args.labels or [Path(r).name for r in args.runs]))
    return 0


if __name__ == "__main__":
    sys.exit(main())
