"""Evaluate a trained network with the paper's protocol (sections 5.2 and 5.3).

    python -m research.evaluate RUN --data DIR [--split test] --out results.json [--mesh-dir DIR]
                             [--resolution 128] [--limit N] [--per-category N] [--oracle structure|all] [--icp]
                             [--bundle BUNDLE_DIR]
                             [--photos [--remove-background auto|true|false] [--foreground FG | --exact-masks] [--box-prompt]]

Each shape is encoded (its octree for an autoencoder, a fixed view of its renders for an image
model), decoded (octrees grow through the shared decode loop), its leaf patches sampled at one
point per sub-patch of the resolution^3 grid, and compared with its ground-truth points by the
Chamfer distance (reported x 10^3, per category and as the category mean, in unit-cube
coordinates).  Shape completion decodes in the partial scan's frame; its output is mapped to the
complete shape's own cube before the comparison, and the Chamfer distance of the partial input
itself to the truth (what a model that adds nothing would score) is reported beside it, and so is
completion's own measure: the mean squared distance from the truth's missing part (points more
than two finest voxels from the scan) to the output, and to the scan itself.  Octree decoders
without planes (O-CNN binary) give their finest octants' centres;
the point-set decoder its points; the AtlasNet decoder a 20 x 20 grid per patch.  Every output is
also measured by the F-score at 1% of the truth's diagonal (Tatarchenko et al., CVPR 2019), which,
unlike the Chamfer distance, does not reward an output spread over the shape's extent.  --icp also
reports both after rigid ICP alignment of the prediction to the truth (as the paper's Table 4; the
alignment kept where it lowers the Chamfer distance).  A shape whose decoder outputs nothing (no
patch) has no Chamfer value: it is
counted in ``empty_outputs`` and left out of the means.  Octree decoders with planes are also
measured through their closed surface (:func:`model.surface.watertight_mesh`, sampled uniformly by
area with as many points, as are the patches for this comparison): the Chamfer distance and the
F-score at 1% of the truth's diagonal of both surfaces, and how many closed surfaces failed to
close.  The results also hold per-shape
values and, for octree decoders, the teacher-forced status accuracy per depth.  Diagnostics: --oracle
structure decodes with the true statuses (separating structure errors from patch errors);
--oracle all also takes the true planes (the representation's own floor).
"""

from __future__ import annotations

import dataclasses
import os
import sys
import time

import numpy as np
import torch
import trimesh

from export.bundle import SERVED_IN, BundleError, load_bundle
from export.runtime import Runtime
from model.checkpoint import Loaded, load_model
from model.cli import command_parser
from model.decode import empty_bias_of
from model.files import json_text, write_atomic
from model.image.mask import MaskSpec
from model.networks import OctreeDecoder
from model.octree.metrics import Reference
from model.octree.symmetry import MIN_SUPPORT
from model.surface import DEFAULT_SURFACE, SURFACES, surface_mesh
from model.train.completion import truth_view
from model.train.images import image_batch, photo_batch
from model.train.tasks import TASKS, encode_with_guide

from .align import icp
from .classification import evaluate_classifier
from .decoding import ORACLES, decoded_points, status_confusion
from .masks import evaluate_foreground, foreground_in_torch
from .measures import fscore_threshold, mean_or_none, missing_rows, split_subset, status_summary, surface_rows


@dataclasses.dataclass(frozen=True)
class EvalOptions:
    """How :func:`evaluate` runs (the command line's options); :meth:`check` says, once, which
    options do not go together or with the model's task.

    ``bundle``: encode and decode with this exported bundle in onnxruntime instead of torch.
    ``normals``: completion inputs built with the scanner's normals or with estimated ones.
    ``surface``: the surface written to ``mesh_dir`` (both are measured).  ``photos``: image models
    see each shape's photo-like test view (a render on a held-out background, no alpha) through the
    service's background removal (the bundle's foreground network; ``remove_background`` as the
    service's parameter), and the mask's IoU with the exact one is reported; without a bundle,
    ``foreground`` (a foreground network's checkpoint or run, in torch) removes the backgrounds, as
    the bundle it would be exported into would; ``exact_masks`` (a diagnostic) sends each photo
    with its exact mask as alpha instead; ``box_prompts``: each photo with a box prompt about its
    object, as a user drags one (the service's ``box=``).  ``keep_scan``: completion outputs keep the scan's own
    patches where it saw the shape (the service's ``keep_scan``).  ``symmetry``: completion inputs
    are read with their mirror image where its plane has at least this support (the service's
    ``symmetry``).  ``per_category``: only the first so many shapes of each category (of the
    split's first ``limit``)."""

    split: str = "test"
    resolution: int = 128
    limit: int | None = None
    per_category: int | None = None
    mesh_dir: str | None = None
    surface: str = DEFAULT_SURFACE
    batch_size: int = 8
    seed: int = 0
    oracle: str = "none"
    align: bool = False
    bundle: str | None = None
    normals: str = "given"
    photos: bool = False
    remove_background: str = "auto"
    foreground: str | None = None
    exact_masks: bool = False
    box_prompts: bool = False
    keep_scan: bool = False
    symmetry: float | None = None

    def check(self, task: str) -> None:
        """ValueError naming the first option that does not go with the others or with ``task``."""
        rules = [
            (self.oracle not in ORACLES, f"--oracle must be one of {', '.join(ORACLES)}"),
            (self.resolution < 2 or self.limit is not None and self.limit < 1,
             "--resolution must be at least 2 and --limit at least 1"),
            (self.photos and task != "image", "--photos goes with an image model"),
            (self.foreground is not None and (not self.photos or self.bundle is not None),
             "--foreground goes with --photos and no --bundle (a bundle brings its own foreground network)"),
            (self.exact_masks and (not self.photos or self.foreground is not None),
             "--exact-masks goes with --photos and takes the place of a foreground network (no --foreground)"),
            (self.box_prompts and not self.photos, "--box-prompt goes with --photos"),
            (self.keep_scan and task != "completion", "--keep-scan goes with a completion model"),
            (self.symmetry is not None and task != "completion", "--symmetry goes with a completion model"),
            (self.per_category is not None and (task in ("classify", "foreground") or self.per_category < 1),
             "--per-category takes a number of shapes >= 1 and goes with a shape model"),
        ]
        for bad, message in rules:
            if bad:
                raise ValueError(message)


def _runtime(options: EvalOptions, loaded: Loaded, run: str) -> Runtime | None:
    """The bundle's onnxruntime sessions (None without ``options.bundle``); ValueError when the
    bundle does not serve the run's kind of model."""
    if options.bundle is None:
        return None
    cfg = loaded.config
    try:
        runtime = Runtime(load_bundle(options.bundle))
    except BundleError as exc:
        raise ValueError(f"--bundle: {exc}") from None
    if cfg.task == "foreground" and not runtime.has_foreground:
        raise ValueError(f"--bundle {options.bundle} has no foreground network")
    if runtime.bundle.task != SERVED_IN.get(cfg.task, cfg.task):
        raise ValueError(f"--bundle {options.bundle} serves {runtime.bundle.task}, but {run} is a {cfg.task} model")
    return runtime


def evaluate(run: str, data: str, options: EvalOptions = EvalOptions()) -> dict:
    """The results dictionary written by the CLI (see the module docstring) of the model of ``run``
    on ``data``."""
    loaded = load_model(run)
    cfg = dataclasses.replace(loaded.config, data=data)    # the dataset to evaluate on (not the training one)
    options.check(cfg.task)
    runtime = _runtime(options, loaded, run)
    if cfg.task == "classify":
        return evaluate_classifier(loaded.model, cfg, run, options.split, options.limit, runtime=runtime,
                                   bundle=options.bundle)
    if cfg.task == "foreground":
        return evaluate_foreground(loaded.model, cfg, run, options.split, options.limit, runtime=runtime,
                                   bundle=options.bundle, meta=loaded.meta)
    if options.oracle != "none" and not isinstance(loaded.model.decoder, OctreeDecoder):
        raise ValueError("--oracle needs an octree decoder")
    if options.mesh_dir:
        try:
            os.makedirs(options.mesh_dir, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"cannot create --mesh-dir {options.mesh_dir}: {exc.strerror}") from None
    return _ShapeEvaluation(run, loaded, cfg, options, runtime).results()


class _ShapeEvaluation:
    """One evaluation of a shape model (autoencoder, image, completion): the inputs encoded a
    batch at a time, each shape decoded and measured (:meth:`row`), the rows summarised."""

    def __init__(self, run: str, loaded: Loaded, cfg, options: EvalOptions, runtime: Runtime | None):
        self.run, self.model, self.cfg, self.o, self.runtime = run, loaded.model, cfg, options, runtime
        self.task = TASKS[cfg.task]
        self.completion = cfg.task == "completion"
        self.octree_decoder = isinstance(self.model.decoder, OctreeDecoder)
        self.fill_bias = None
        if options.keep_scan:     # the decode setting chosen for keep_scan outputs: the bundle's when it is served
            self.fill_bias = (runtime.bundle.keep_scan_bias if runtime is not None
                              else empty_bias_of(loaded.meta.get("keep_scan")))
        extra = {"normals": options.normals, "symmetry": options.symmetry} if self.completion else {}
        self.records = self.task.dataset(cfg, options.split, options.seed, points=20_000, limit=options.limit, **extra)
        self.chosen = split_subset(cfg.data, options.split, cfg.categories, options.limit, len(self.records),
                                   options.per_category)
        self.surfaces = self.octree_decoder and self.model.decoder.has_plane(cfg.depth)
        self.metrics = self._metrics()
        if options.foreground is not None:
            self.segment, self.mask_spec = foreground_in_torch(options.foreground)
        else:
            self.segment = runtime.segment if runtime is not None and runtime.has_foreground else None
            self.mask_spec = (runtime.bundle.mask_spec() if self.segment is not None else None) or MaskSpec()

    def _metrics(self) -> tuple[str, ...]:
        o = self.o
        metrics = ("chamfer_x1e3", "fscore") + (("chamfer_icp_x1e3", "fscore_icp") if o.align else ())
        if self.surfaces:
            metrics += ("patches_area_chamfer_x1e3", "patches_area_fscore", "watertight_chamfer_x1e3",
                        "watertight_fscore")
        if self.completion:
            metrics += ("input_chamfer_x1e3", "missing_x1e3", "input_missing_x1e3")
        return metrics + (("mask_iou",) if o.photos else ())

    def encode(self, idx: np.ndarray, octree) -> tuple[torch.Tensor, object, list[dict]]:
        """Latent codes of shapes ``idx``, a guided decoder's guide, and each photo's framing."""
        samples = [self.records.samples[i] for i in idx]
        rt = self.runtime
        if self.o.photos:
            images, framing = photo_batch(samples, self.task.spec(self.cfg), self.segment, self.o.remove_background,
                                          self.mask_spec, self.o.exact_masks, self.o.box_prompts)
            with torch.no_grad():
                latent = (torch.from_numpy(rt.encode_image(images)) if rt is not None
                          else self.model.encoder(torch.from_numpy(images)))
            return latent, None, framing
        framing = [{}] * len(idx)
        if rt is None:
            with torch.no_grad():
                latent, guide = encode_with_guide(self.model, self.cfg, self.records, idx)
            return latent, guide, framing
        if self.cfg.task == "image":
            return torch.from_numpy(rt.encode_image(image_batch(samples, self.task.spec(self.cfg), None))), None, framing
        latent, guide = rt.encode_scan(self.records.pairs(idx)[0] if self.completion else octree)
        return torch.from_numpy(latent), guide, framing

    def row(self, i: int, frame: dict, pts: np.ndarray, tree) -> dict:
        """The measures of shape ``i`` decoded to ``pts`` (and ``tree``), its decoded meshes written."""
        o, sample = self.o, self.records.samples[i]
        pts = truth_view(sample, pts)
        row = {"category": sample.category, "shape_id": sample.shape_id,
               "truth_nodes": int(sum(sample.octree.nodes_per_depth())), "output_points": int(len(pts)), **frame}
        truth = Reference(sample.points)
        if len(pts):
            near = truth.nearest(pts)
            threshold = fscore_threshold(truth.points)
            row.update(chamfer_x1e3=near.chamfer() * 1e3, fscore=near.fscore(threshold))
            if o.align:       # the alignment is kept where it lowers the Chamfer distance
                moved = truth.nearest(icp(pts, sample.points).apply(pts)) if len(pts) >= 3 else near
                better = moved.chamfer() * 1e3 < row["chamfer_x1e3"]
                row["chamfer_icp_x1e3"] = moved.chamfer() * 1e3 if better else row["chamfer_x1e3"]
                row["fscore_icp"] = moved.fscore(threshold) if better else row["fscore"]
            if self.surfaces:
                row.update(surface_rows(sample, truth, tree, max(len(pts), 1000), o.seed, threshold))
        else:
            row.update({m: None for m in self.metrics if m != "mask_iou"})
        if sample.partial is not None:        # the do-nothing floor: the input itself
            row["input_chamfer_x1e3"] = truth.chamfer(sample.partial) * 1e3
            row.update(missing_rows(sample, pts))
        if tree is not None:
            row["decoded_nodes"] = int(sum(tree.nodes_per_depth()))
            row["decoded_leaves"] = int(sum(tree.leaves_per_depth()))
            if o.mesh_dir and self.model.decoder.has_plane(tree.depth) and len(pts):
                tree.normalizations = [sample.octree.normalizations[0]]
                m = surface_mesh(tree, o.surface)
                write_atomic(os.path.join(o.mesh_dir, f"{sample.shape_id}.ply"),
                             trimesh.Trimesh(m.vertices, m.faces, process=False).export(file_type="ply"))
        return row

    def results(self) -> dict:
        o, per_shape, confusion = self.o, [], {}
        t = time.perf_counter()
        scans = self.records.scan if o.keep_scan else None
        for s in range(0, len(self.chosen), o.batch_size):
            idx = self.chosen[s:s + o.batch_size]
            octree, _ = self.records.batch(idx)
            latent, guide, framing = self.encode(idx, octree)
            if self.octree_decoder:
                for d, m in status_confusion(self.model, latent, octree, guide).items():
                    confusion[d] = confusion.get(d, 0) + m
            decoded = decoded_points(self.model, latent, octree, o.resolution, o.seed, o.oracle,
                                     self.runtime and self.runtime.steps(), scans and [scans(i) for i in idx],
                                     self.fill_bias, guide)
            per_shape += [self.row(i, frame, pts, tree) for i, frame, (pts, tree) in zip(idx, framing, decoded)]
        return self.summary(per_shape, confusion, time.perf_counter() - t)

    def summary(self, per_shape: list[dict], confusion: dict, seconds: float) -> dict:
        o, cfg = self.o, self.cfg
        results = {"run": str(self.run), "task": cfg.task, "arch": cfg.arch, "depth": cfg.depth, "split": o.split,
                   "resolution": o.resolution, "bundle": o.bundle, "shapes": len(per_shape),
                   "empty_outputs": sum(1 for r in per_shape if not r["output_points"]), "oracle": o.oracle,
                   "per_category": o.per_category}
        if o.photos:
            sources = [r["mask_source"] for r in per_shape]
            results["input"] = {"kind": "photos", "remove_background": o.remove_background,
                                "foreground_network": self.segment is not None and not o.exact_masks,
                                "foreground": o.foreground, "exact_masks": o.exact_masks,
                                "box_prompts": o.box_prompts,
                                "mask_sources": {k: sources.count(k) for k in sorted(set(sources))}}
        if self.surfaces:
            results["watertight_not_closed"] = sum(1 for r in per_shape if r.get("watertight_closed") is False)
            results["watertight_crossing"] = sum(1 for r in per_shape if (r.get("watertight_crossing_share") or 0) > 0)
        for m in self.metrics:
            per_cat: dict[str, list[float]] = {}
            for r in per_shape:
                if r.get(m) is not None:
                    per_cat.setdefault(r["category"], []).append(r[m])
            results[m] = means = {c: float(np.mean(v)) for c, v in sorted(per_cat.items())}
            results[f"{m}_category_mean"] = mean_or_none(list(means.values()))
        sizes = {k: [r[k] for r in per_shape if k in r] for k in ("decoded_nodes", "truth_nodes", "decoded_leaves")}
        results.update({"octree": {k: mean_or_none(v) for k, v in sizes.items()},
                        "status": {str(d): status_summary(m) for d, m in sorted(confusion.items())},
                        "per_shape": per_shape, "seconds": seconds})
        if cfg.task == "image":
            results["encoder"] = cfg.encoder
        if self.completion:
            results.update(normals=o.normals, keep_scan=o.keep_scan, symmetry=o.symmetry,
                           keep_scan_empty_bias={str(d): b for d, b in sorted((self.fill_bias or {}).items())})
        return results


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.evaluate", __doc__, [
        "python -m research.evaluate runs/aocnn --data data/procedural --split test --out results.json",
        "python -m research.evaluate models/checkpoints/completion --data data/procedural "
        "--bundle models/bundles/completion --out c.json"])
    ap.add_argument("run", help="run folder of python -m model.train (holds checkpoint.pt) or a checkpoint "
                    "folder (model.pt + model.json)")
    ap.add_argument("--data", required=True, help="dataset folder built by python -m model.data build")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"), help="split to evaluate (default test)")
    ap.add_argument("--out", required=True, help="results JSON")
    ap.add_argument("--mesh-dir", default=None, help="write decoded meshes (PLY) here")
    ap.add_argument("--surface", choices=SURFACES, default=DEFAULT_SURFACE,
                    help=f"the surface written to --mesh-dir; both are measured (default {DEFAULT_SURFACE})")
    ap.add_argument("--resolution", type=int, default=128,
                    help="patch sampling grid: one point per sub-patch of resolution^3 (default 128, the paper's)")
    ap.add_argument("--limit", type=int, default=None, help="evaluate at most this many shapes (default all)")
    ap.add_argument("--per-category", type=int, default=None,
                    help="only the first N shapes of each category (a smaller subset every category is in)")
    ap.add_argument("--oracle", choices=ORACLES, default="none",
                    help="diagnostic: decode with the true statuses ('structure') and planes ('all'); default none")
    ap.add_argument("--icp", action="store_true",
                    help="also report the Chamfer distance after rigid ICP alignment to the truth (paper Table 4)")
    ap.add_argument("--bundle", default=None,
                    help="run the model's exported ONNX bundle in onnxruntime instead of torch (default: torch)")
    ap.add_argument("--photos", action="store_true",
                    help="image models: evaluate on each shape's photo-like view (a render on a held-out "
                         "background, no alpha) through the bundle's background removal (or --foreground's), and report "
                         "the mask IoU")
    ap.add_argument("--remove-background", choices=("auto", "true", "false"), default="auto",
                    help="with --photos: the service's parameter (default auto: the bundle's foreground network)")
    ap.add_argument("--foreground", default=None,
                    help="with --photos and no --bundle: a foreground network's checkpoint or run folder (in torch) "
                         "that removes the backgrounds, as in the bundle it would be exported into")
    ap.add_argument("--exact-masks", action="store_true",
                    help="diagnostic, with --photos: send each photo with its exact mask as alpha (what a perfect "
                         "foreground network would give) instead of removing its background")
    ap.add_argument("--box-prompt", action="store_true",
                    help="with --photos: send each photo with a box prompt about its object (the object's box 5%% "
                         "larger, as a user drags one; the service's box=)")
    ap.add_argument("--normals", choices=("given", "estimated"), default="given",
                    help="completion: build the partial scans' octrees with the scanner's normals (default) "
                         "or with normals estimated from the points")
    ap.add_argument("--keep-scan", action="store_true",
                    help="completion: keep the scan's own patches where it saw the shape, the network's "
                         "elsewhere (the service's keep_scan)")
    ap.add_argument("--symmetry", action="store_true",
                    help="completion: read each scan with its mirror image when its left-right mirror plane is "
                         f"supported well enough (at least {MIN_SUPPORT:.0%}% of it lands on itself; the service's "
                         "symmetry)")
    args = ap.parse_args(argv)
    try:
        folder = os.path.dirname(os.path.abspath(args.out))
        if not os.path.isdir(folder):
            raise ValueError(f"--out {args.out}: the folder {folder} does not exist")
        options = EvalOptions(args.split, args.resolution, args.limit, args.per_category, args.mesh_dir, args.surface,
                              oracle=args.oracle, align=args.icp, bundle=args.bundle, normals=args.normals,
                              photos=args.photos, remove_background=args.remove_background,
                              foreground=args.foreground, exact_masks=args.exact_masks, box_prompts=args.box_prompt,
                              keep_scan=args.keep_scan,
                              symmetry=MIN_SUPPORT if args.symmetry else None)
        results = evaluate(args.run, args.data, options)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    write_atomic(args.out, json_text(results).encode())
    if "voted_accuracy" in results:
        print(f"{args.out}: {results['shapes']} shapes, accuracy {results['accuracy']:.4f}, "
              f"voted over 12 rotations {results['voted_accuracy']:.4f}")
        return 0
    if results["task"] == "foreground":
        print(f"{args.out}: {results['shapes']} photos, mask IoU category mean {results['mask_iou_category_mean']:.4f} "
              f"(median {results['mask_iou_median']:.4f}; above 0.9: {results['mask_iou_above_0.9']:.1%}), "
              f"thin-part recall category mean {results['thin_recall_category_mean']:.4f}"
              f"{' (with the refinement network)' if results['refined'] else ''}")
        return 0
    mean = results["chamfer_x1e3_category_mean"]
    text = f"{args.out}: {results['shapes']} shapes, Chamfer x1e3 category mean "
    text += f"{mean:.3f}" if mean is not None else "n/a"
    if args.icp and results["chamfer_icp_x1e3_category_mean"] is not None:
        text += f" ({results['chamfer_icp_x1e3_category_mean']:.3f} after ICP)"
    if results.get("fscore_category_mean") is not None:
        text += f", F-score {results['fscore_category_mean']:.3f}"
    if results.get("input_chamfer_x1e3_category_mean") is not None:
        text += f"; the partial inputs themselves {results['input_chamfer_x1e3_category_mean']:.3f}"
    if results.get("watertight_chamfer_x1e3_category_mean") is not None:
        text += (f"; drawn by area: patches {results['patches_area_chamfer_x1e3_category_mean']:.3f}, closed surface "
                 f"{results['watertight_chamfer_x1e3_category_mean']:.3f} "
                 f"(F-score {results['patches_area_fscore_category_mean']:.3f}"
                 f" and {results['watertight_fscore_category_mean']:.3f}; {results['watertight_not_closed']} not closed, "
                 f"{results['watertight_crossing']} with faces crossing others)")
    if results.get("mask_iou_category_mean") is not None:
        text += f"; mask IoU {results['mask_iou_category_mean']:.3f}"
    print(text)
    if results["empty_outputs"]:
        print(f"warning: {results['empty_outputs']} of {results['shapes']} shapes decoded to nothing (no patch: "
              "every octant was predicted empty) and are left out of the means; the model is probably "
              "under-trained", file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
