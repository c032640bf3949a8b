"""Evaluate a trained autoencoder with the paper's protocol (section 5.2).

    python -m model.evaluate RUN --data DIR [--split test] --out results.json [--mesh-dir DIR]
                             [--resolution 128] [--limit N] [--oracle structure|all]

Each shape is encoded, decoded by growing its octree (the shared decode loop), its leaf patches
sampled at one point per sub-patch of the resolution^3 grid, and compared with its ground-truth
points by the Chamfer distance (reported x 10^3, per category and as the category mean, in
unit-cube coordinates).  Octree decoders without planes (O-CNN binary) give their finest
octants' centres; the point-set decoder gives its points.  The results also hold per-shape
values and, for octree decoders, the teacher-forced status accuracy per depth.  Diagnostics:
--oracle structure decodes with the true statuses (separating structure errors from patch
errors); --oracle all also takes the true planes (the representation's own floor).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np
import torch

from .decode import decode
from .files import write_atomic
from .networks import ARCHS, TorchSteps
from .nn.tensors import OctreeTensors
from .octree import LEAF, Octree
from .octree.metrics import chamfer_distance, sample_patches
from .octree.patches import patches_to_mesh
from .octree.batch import split_octree
from .train.data import RecordSet
from .train.loop import TrainConfig, build_model, load_checkpoint


def load_run(run: str | Path) -> tuple[torch.nn.Module, TrainConfig]:
    """The trained model (eval mode) and the configuration of a run folder."""
    state = load_checkpoint(Path(run) / "checkpoint.pt")
    cfg = TrainConfig(**state["config"])
    model = build_model(cfg)
    model.load_state_dict(state["model"])
    return model.eval(), cfg


ORACLES = ("none", "structure", "all")


class Oracle:
    """Decoder steps whose statuses (and with ``planes``, planes) are the ground truth's:
    separates the Chamfer lost to wrong structure, to wrong patches, and to the representation."""

    def __init__(self, steps: TorchSteps, truth: Octree, planes: bool = False):
        self.steps, self.truth, self.depth, self.planes = steps, truth, steps.depth, planes

    def classes(self, depth: int) -> int:
        return self.steps.classes(depth)

    def start(self, latent):
        return self.steps.start(latent)

    def predict(self, depth: int, x, neighbors: np.ndarray):
        x, logits, plane = self.steps.predict(depth, x, neighbors)
        label = torch.from_numpy(self.truth.levels[depth].label)
        status = self.steps.decoder.status_targets(depth, label).numpy()
        if self.planes and plane is not None:
            plane = self.truth.levels[depth].plane
        return x, np.eye(self.classes(depth), dtype=np.float32)[status], plane

    def expand(self, depth: int, x, split: np.ndarray):
        return self.steps.expand(depth, x, split)


def status_confusion(model, latent: torch.Tensor, tensors: OctreeTensors) -> dict[int, np.ndarray]:
    """Per depth, the confusion matrix (truth x predicted status) of teacher-forced predictions."""
    dec = model.decoder
    with torch.no_grad():
        outputs = dec(latent, tensors)
    out = {}
    for (logits, _), d in zip(outputs, range(dec.full_depth, dec.depth + 1)):
        k = dec.classes(d)
        truth = dec.status_targets(d, tensors.levels[d].label).numpy()
        pred = logits.argmax(1).numpy()
        out[d] = np.bincount(truth * k + pred, minlength=k * k).reshape(k, k)
    return out


def decoded_points(model, latent: torch.Tensor, octree_batch: Octree, resolution: int, seed: int,
                   oracle: str = "none") -> list[tuple[np.ndarray, Octree | None]]:
    """Per shape of the batch: decoded points in cube coordinates, and the decoded octree (or None)."""
    if model.arch.decoder == "psg":
        with torch.no_grad():
            pts = model.decoder(latent).numpy()
        return [(p.astype(np.float64), None) for p in pts]
    steps = TorchSteps(model.decoder)
    out = []
    if oracle != "none":
        steps = Oracle(steps, octree_batch, planes=oracle == "all")
    for tree in split_octree(decode(steps, latent.numpy())):
        if model.decoder.has_plane(tree.depth):
            pts = sample_patches(tree, resolution=resolution, seed=seed, world=False)
        else:
            lv = tree.levels[-1]
            pts = lv.centers()[lv.label == LEAF]
        out.append((pts, tree))
    return out


def evaluate(run: str, data: str, split: str = "test", resolution: int = 128, limit: int | None = None,
             mesh_dir: str | None = None, batch_size: int = 8, seed: int = 0, oracle: str = "none") -> dict:
    """The results dictionary written by the CLI (see the module docstring)."""
    if oracle not in ORACLES:
        raise ValueError(f"--oracle must be one of {', '.join(ORACLES)}")
    model, cfg = load_run(run)
    if oracle != "none" and model.arch.decoder == "psg":
        raise ValueError("--oracle needs an octree decoder, not psg")
    if mesh_dir:
        try:
            os.makedirs(mesh_dir, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"cannot create --mesh-dir {mesh_dir}: {exc.strerror}") from None
    kind = ARCHS[cfg.arch].octree
    records = RecordSet(data, split, kind, points=20_000, depth=cfg.depth, limit=limit, seed=seed)
    per_cat: dict[str, list[float]] = {}
    per_shape: list[dict] = []
    confusion: dict[int, np.ndarray] = {}
    sizes = {"decoded_nodes": [], "truth_nodes": [], "decoded_leaves": []}
    t = time.perf_counter()
    for s in range(0, len(records), batch_size):
        idx = np.arange(s, min(len(records), s + batch_size))
        octree, _ = records.batch(idx)
        tensors = OctreeTensors.from_octree(octree)
        with torch.no_grad():
            latent = model.encoder(tensors)
        if model.arch.decoder != "psg":
            for d, m in status_confusion(model, latent, tensors).items():
                confusion[d] = confusion.get(d, 0) + m
        for i, (pts, tree) in zip(idx, decoded_points(model, latent, octree, resolution, seed, oracle)):
            sample = records.samples[i]
            cd = chamfer_distance(sample.points, pts) if len(pts) else float("inf")
            per_cat.setdefault(sample.category, []).append(cd * 1e3)
            row = {"category": sample.category, "shape_id": sample.shape_id, "chamfer_x1e3": cd * 1e3,
                   "truth_nodes": int(sum(sample.octree.nodes_per_depth()))}
            sizes["truth_nodes"].append(row["truth_nodes"])
            if tree is not None:
                row["decoded_nodes"] = int(sum(tree.nodes_per_depth()))
                sizes["decoded_nodes"].append(row["decoded_nodes"])
                sizes["decoded_leaves"].append(sum(tree.leaves_per_depth()))
                if mesh_dir and model.decoder.has_plane(tree.depth):
                    tree.normalizations = [sample.octree.normalizations[0]]
                    write_atomic(os.path.join(mesh_dir, f"{sample.shape_id}.ply"),
                                 patches_to_mesh(tree).export(file_type="ply"))
            per_shape.append(row)
    means = {c: float(np.mean(v)) for c, v in sorted(per_cat.items())}
    return {
        "run": str(run), "arch": cfg.arch, "depth": cfg.depth, "split": split, "resolution": resolution,
        "shapes": int(sum(len(v) for v in per_cat.values())),
        "chamfer_x1e3": means, "chamfer_x1e3_category_mean": float(np.mean(list(means.values()))),
        "oracle": oracle,
        "octree": {k: float(np.mean(v)) if v else None for k, v in sizes.items()},
        "status": {str(d): status_summary(m) for d, m in sorted(confusion.items())},
        "per_shape": per_shape,
        "seconds": time.perf_counter() - t,
    }


def status_summary(confusion: np.ndarray) -> dict:
    """Accuracy, per-class recall and precision, and the confusion matrix (rows: truth)."""
    c = confusion.astype(np.float64)
    names = ["empty", "split", "leaf"] if len(c) == 3 else ["empty", "non-empty"]
    recall = np.diag(c) / np.maximum(c.sum(1), 1)
    precision = np.diag(c) / np.maximum(c.sum(0), 1)
    return {"accuracy": float(np.trace(c) / max(c.sum(), 1)),
            "recall": dict(zip(names, recall.round(4).tolist())),
            "precision": dict(zip(names, precision.round(4).tolist())),
            "truth_count": dict(zip(names, c.sum(1).astype(int).tolist())),
            "predicted_count": dict(zip(names, c.sum(0).astype(int).tolist())),
            "confusion": confusion.astype(int).tolist()}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m model.evaluate", description=__doc__.splitlines()[0])
    ap.add_argument("run")
    ap.add_argument("--data", required=True)
    ap.add_argument("--split", default="test")
    ap.add_argument("--out", required=True, help="results JSON")
    ap.add_argument("--mesh-dir", default=None, help="write decoded patch meshes (PLY) here")
    ap.add_argument("--resolution", type=int, default=128)
    ap.add_argument("--limit", type=int, default=None)
    ap.add_argument("--oracle", choices=ORACLES, default="none",
                    help="diagnostic: decode with the true statuses ('structure') and planes ('all')")
    args = ap.parse_args(argv)
    try:
        folder = os.path.dirname(os.path.abspath(args.out))
        if not os.path.isdir(folder):
            raise ValueError(f"--out {args.out}: the folder {folder} does not exist")
        if args.resolution < 2 or args.limit is not None and args.limit < 1:
            raise ValueError("--resolution must be at least 2 and --limit at least 1")
        results = evaluate(args.run, args.data, args.split, args.resolution, args.limit, args.mesh_dir,
                           oracle=args.oracle)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    write_atomic(args.out, (json.dumps(results, indent=1) + "\n").encode())
    print(f"{args.out}: {results['shapes']} shapes, Chamfer x1e3 category mean "
          f"{results['chamfer_x1e3_category_mean']:.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
