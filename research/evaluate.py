"""Evaluate a trained network with the paper's protocol (sections 5.2 and 5.3).

    python -m research.evaluate RUN --data DIR [--split test] --out results.json [--mesh-dir DIR]
                             [--resolution 128] [--limit N] [--per-category N] [--oracle structure|all] [--icp]
                             [--bundle BUNDLE_DIR]
                             [--photos [--remove-background auto|true|false] [--foreground FG | --exact-masks]]

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
from pathlib import Path

import numpy as np
import torch
import trimesh

from export.bundle import SERVED_IN, BundleError, load_bundle
from export.runtime import Runtime
from model.checkpoint import load_model
from model.cli import command_parser
from model.data.photos import photo_split_view
from model.decode import Guide, decode, empty_bias_of
from model.files import json_text, write_atomic
from model.image.mask import MaskSpec, NoObjectError, mask_input, mask_iou, mask_output, object_mask
from model.networks import AtlasNetDecoder, OctreeDecoder, PointSetDecoder, TorchSteps
from model.networks.decoder import teacher_skips
from model.nn.tensors import OctreeTensors
from model.octree import LEAF, Octree
from model.octree.batch import split_octree
from model.octree.fuse import keep_scan
from model.octree.geometry import ROTATIONS
from model.octree.metrics import Reference, mean_squared_distance, missing_part, sample_patches
from model.octree.symmetry import MIN_SUPPORT
from model.surface import DEFAULT_SURFACE, SURFACES, surface_mesh
from model.train.completion import truth_view
from model.train.config import TrainConfig
from model.train.data import manifest_rows
from model.train.images import image_batch, photo_batch
from model.train.tasks import TASKS, encode_with_guide

from .align import icp
from .results import category_means

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

    def predict(self, depth: int, x, neighbors: np.ndarray, *skip):
        x, logits, plane = self.steps.predict(depth, x, neighbors, *skip)
        label = torch.from_numpy(self.truth.levels[depth].label)
        status = self.steps.decoder.status_targets(depth, label).numpy()
        if self.planes and plane is not None:
            plane = self.truth.levels[depth].plane
        return x, np.eye(self.classes(depth), dtype=np.float32)[status], plane

    def expand(self, depth: int, x, split: np.ndarray):
        return self.steps.expand(depth, x, split)


def status_confusion(model, latent: torch.Tensor, octree: Octree, guide: Guide | None = None
                     ) -> dict[int, np.ndarray]:
    """Per depth, the confusion matrix (truth x predicted status) of predictions teacher-forced
    over ``octree`` (a guided decoder with its input's ``guide``)."""
    dec = model.decoder
    tensors = OctreeTensors.from_octree(octree)
    with torch.no_grad():
        outputs = dec(latent, tensors, teacher_skips(guide, octree))
    out = {}
    for (logits, _), d in zip(outputs, range(dec.full_depth, dec.depth + 1)):
        k = dec.classes(d)
        truth = dec.status_targets(d, tensors.levels[d].label).numpy()
        pred = logits.argmax(1).numpy()
        out[d] = np.bincount(truth * k + pred, minlength=k * k).reshape(k, k)
    return out


ATLAS_GRID = 20
"""AtlasNet evaluation: a 20 x 20 uv grid per patch (10,000 points for 25 patches)."""


def decoded_points(model, latent: torch.Tensor, octree_batch: Octree | None, resolution: int, seed: int,
                   oracle: str = "none", steps=None, scans: list[Octree] | None = None,
                   empty_bias: dict[int, float] | None = None, guide: Guide | None = None
                   ) -> list[tuple[np.ndarray, Octree | None]]:
    """Per shape of the batch: decoded points in cube coordinates, and the decoded octree (or None).
    ``steps``: the decoder steps to grow octrees with (default: the torch decoder's).  ``scans``:
    each shape's input scan octree, kept where it saw the shape (:func:`keep_scan`); ``empty_bias``
    and ``guide`` (a guided decoder's input) as :func:`model.decode.decode`'s."""
    dec = model.decoder
    if isinstance(dec, (PointSetDecoder, AtlasNetDecoder)):
        with torch.no_grad():
            pts = (dec.grid(latent, ATLAS_GRID) if isinstance(dec, AtlasNetDecoder) else dec(latent)).numpy()
        return [(p.astype(np.float64), None) for p in pts]
    steps = steps or TorchSteps(dec)
    out = []
    if oracle != "none":
        steps = Oracle(steps, octree_batch, planes=oracle == "all")
    for b, tree in enumerate(split_octree(decode(steps, latent.numpy(), empty_bias=empty_bias, guide=guide), neighbors=False)):
        if scans is not None:
            tree = keep_scan(tree, scans[b])
        if dec.has_plane(tree.depth):
            pts = sample_patches(tree, resolution=resolution, seed=seed, world=False)
        else:
            lv = tree.levels[-1]
            pts = lv.centers()[lv.label == LEAF]
        out.append((pts, tree))
    return out


MISSING_GAP = 2 / 64
"""Truth points farther than this from the partial scan (in the truth's unit cube: two voxels at
depth 6) form its missing part: the same part of every shape for models of any depth."""


FSCORE_SHARE = 0.01
"""F-score threshold: 1% of the truth's bounding-box diagonal (Tatarchenko et al., CVPR 2019)."""


def fscore_threshold(truth: np.ndarray) -> float:
    """The F-score's distance threshold for a shape: :data:`FSCORE_SHARE` of its diagonal."""
    return FSCORE_SHARE * float(np.linalg.norm(truth.max(0) - truth.min(0)))


def surface_rows(sample, truth: Reference, tree: Octree, count: int, seed: int, threshold: float) -> dict:
    """Chamfer (x1e3) and F-score (at ``threshold``) of both surfaces of the decoded octree against
    the truth, and whether the closed one is closed.  The surfaces are measured on ``count``
    points drawn uniformly at random by area (as many as the output's, at least 1,000): random
    draws leave gaps that a stratified protocol does not, so only draws of the same kind compare
    the two surfaces (the patches are measured both ways)."""
    row = {}
    for kind in SURFACES:
        m = surface_mesh(tree, kind, world=False)
        name = "watertight" if kind == "watertight" else "patches_area"
        if kind == "watertight":
            row["watertight_closed"] = m.closed
        if not len(m.faces):
            row.update({f"{name}_chamfer_x1e3": None, f"{name}_fscore": None})
            continue
        drawn = trimesh.sample.sample_surface(trimesh.Trimesh(m.vertices, m.faces, process=False), count, seed=seed)[0]
        near = truth.nearest(truth_view(sample, drawn))
        row.update({f"{name}_chamfer_x1e3": near.chamfer() * 1e3, f"{name}_fscore": near.fscore(threshold)})
    return row


def _missing(sample, pts: np.ndarray) -> dict:
    """Completion rows: the missing part's distance to the output and to the input itself."""
    part = missing_part(sample.points, sample.partial, MISSING_GAP)
    if not len(part):
        return {"missing_x1e3": None, "input_missing_x1e3": None}
    return {"missing_x1e3": mean_squared_distance(part, pts) * 1e3 if len(pts) else None,
            "input_missing_x1e3": mean_squared_distance(part, sample.partial) * 1e3}


def _mean_or_none(values: list[float]) -> float | None:
    return float(np.mean(values)) if values else None


def first_of_each(categories: list[str], n: int) -> np.ndarray:
    """Indices of the first ``n`` items of each category in ``categories`` (one per item), ascending."""
    seen: dict[str, int] = {}
    keep = []
    for i, c in enumerate(categories):
        seen[c] = seen.get(c, 0) + 1
        if seen[c] <= n:
            keep.append(i)
    return np.asarray(keep, dtype=np.int64)


def split_subset(data: str | Path, split: str, categories: tuple[str, ...] | None, limit: int | None,
                 count: int, per_category: int | None) -> np.ndarray:
    """Indices into a dataset of ``count`` shapes of ``split`` (the manifest's rows, in its order):
    all of them, or with ``per_category`` the first so many of each category."""
    if per_category is None:
        return np.arange(count)
    rows = manifest_rows(Path(data), split, None, categories, limit)[1]
    if len(rows) != count:
        raise ValueError(f"the {split} split has {count} shapes but {len(rows)} manifest rows")
    return first_of_each([r["category"] for r in rows], per_category)


def evaluate(run: str, data: str, split: str = "test", resolution: int = 128, limit: int | None = None,
             mesh_dir: str | None = None, batch_size: int = 8, seed: int = 0, oracle: str = "none",
             align: bool = False, bundle: str | None = None, normals: str = "given",
             surface: str = DEFAULT_SURFACE, photos: bool = False, remove_background: str = "auto",
             keep_scan: bool = False, symmetry: float | None = None,
             per_category: int | None = None, foreground: str | None = None, exact_masks: bool = False) -> dict:
    """The results dictionary written by the CLI (see the module docstring).  ``bundle``: encode
    and decode with this exported bundle in onnxruntime instead of the torch model.  ``normals``:
    completion inputs built with the scanner's normals or with estimated ones.  ``surface``: the
    surface written to ``mesh_dir`` (both are measured).  ``photos``: image models see each shape's
    photo-like test view (a render on a held-out background, no alpha) through the service's
    background removal (the bundle's foreground network; ``remove_background`` as the service's
    parameter), and the mask's IoU with the exact one is reported; without a bundle, ``foreground``
    (a foreground network's checkpoint or run, in torch: :func:`foreground_in_torch`) removes the
    backgrounds, as the bundle it would be exported into would; ``exact_masks`` (a diagnostic) sends
    each photo with its exact mask as alpha instead, what a perfect foreground network would give.
    ``keep_scan``: completion outputs keep the scan's own patches where it saw the shape
    (:func:`model.octree.fuse.keep_scan`, the service's ``keep_scan``).  ``symmetry``: completion
    inputs are read with their mirror image where its plane has at least this support
    (:mod:`model.octree.symmetry`, the service's ``symmetry``).  ``per_category``: only the first
    so many shapes of each category (of the split's first ``limit``), a subset that every category
    is in."""
    if oracle not in ORACLES:
        raise ValueError(f"--oracle must be one of {', '.join(ORACLES)}")
    loaded = load_model(run)
    model, cfg = loaded.model, loaded.config
    cfg = dataclasses.replace(cfg, data=data)          # the dataset to evaluate on (not the training one)
    runtime = None
    if bundle is not None:
        try:
            runtime = Runtime(load_bundle(bundle))
        except BundleError as exc:
            raise ValueError(f"--bundle: {exc}") from None
        want = SERVED_IN.get(cfg.task, cfg.task)
        if cfg.task == "foreground" and not runtime.has_foreground:
            raise ValueError(f"--bundle {bundle} has no foreground network")
        if runtime.bundle.task != want:
            raise ValueError(f"--bundle {bundle} serves {runtime.bundle.task}, but {run} is a {cfg.task} model")
    if photos and cfg.task != "image":
        raise ValueError("--photos goes with an image model")
    if foreground is not None and (not photos or bundle is not None):
        raise ValueError("--foreground goes with --photos and no --bundle (a bundle brings its own foreground network)")
    if exact_masks and (not photos or foreground is not None):
        raise ValueError("--exact-masks goes with --photos and takes the place of a foreground network (no --foreground)")
    if keep_scan and cfg.task != "completion":
        raise ValueError("--keep-scan goes with a completion model")
    if symmetry is not None and cfg.task != "completion":
        raise ValueError("--symmetry goes with a completion model")
    if per_category is not None and (cfg.task in ("classify", "foreground") or per_category < 1):
        raise ValueError("--per-category takes a number of shapes >= 1 and goes with a shape model")
    if cfg.task == "classify":
        return evaluate_classifier(model, cfg, run, split, limit, runtime=runtime, bundle=bundle)
    if cfg.task == "foreground":
        return evaluate_foreground(model, cfg, run, split, limit, runtime=runtime, bundle=bundle, meta=loaded.meta)
    octree_decoder = isinstance(model.decoder, OctreeDecoder)
    if oracle != "none" and not octree_decoder:
        raise ValueError("--oracle needs an octree decoder")
    if mesh_dir:
        try:
            os.makedirs(mesh_dir, exist_ok=True)
        except OSError as exc:
            raise ValueError(f"cannot create --mesh-dir {mesh_dir}: {exc.strerror}") from None
    task = TASKS[cfg.task]
    completion = cfg.task == "completion"
    fill_bias = None
    if keep_scan:     # the decode setting chosen for keep_scan outputs: the bundle's when it is served
        fill_bias = runtime.bundle.keep_scan_bias if runtime is not None else empty_bias_of(loaded.meta.get("keep_scan"))
    extra = {"normals": normals, "symmetry": symmetry} if completion else {}
    records = task.dataset(cfg, split, seed, points=20_000, limit=limit, **extra)
    chosen = split_subset(data, split, cfg.categories, limit, len(records), per_category)
    metrics = ("chamfer_x1e3", "fscore") + (("chamfer_icp_x1e3", "fscore_icp") if align else ())
    surfaces = octree_decoder and model.decoder.has_plane(cfg.depth)
    if surfaces:
        metrics += ("patches_area_chamfer_x1e3", "patches_area_fscore", "watertight_chamfer_x1e3",
                    "watertight_fscore")
    if completion:
        metrics += ("input_chamfer_x1e3", "missing_x1e3", "input_missing_x1e3")
    if photos:
        metrics += ("mask_iou",)
    if foreground is not None:
        segment, mask_spec = foreground_in_torch(foreground)
    else:
        segment = runtime.segment if runtime is not None and runtime.has_foreground else None
        mask_spec = (runtime.bundle.mask_spec() if segment is not None else None) or MaskSpec()
    per_cat: dict[str, dict[str, list[float]]] = {m: {} for m in metrics}
    per_shape: list[dict] = []
    confusion: dict[int, np.ndarray] = {}
    sizes = {"decoded_nodes": [], "truth_nodes": [], "decoded_leaves": []}
    empty = 0
    t = time.perf_counter()
    for s in range(0, len(chosen), batch_size):
        idx = chosen[s:s + batch_size]
        octree, _ = records.batch(idx)
        framing = [{}] * len(idx)
        guide = None
        if photos:
            images, framing = photo_batch([records.samples[i] for i in idx], task.spec(cfg), segment,
                                          remove_background, mask_spec, exact_masks)
            with torch.no_grad():
                latent = (torch.from_numpy(runtime.encode_image(images)) if runtime is not None
                          else model.encoder(torch.from_numpy(images)))
        elif runtime is None:
            with torch.no_grad():
                latent, guide = encode_with_guide(model, cfg, records, idx)
        elif cfg.task == "image":
            latent = torch.from_numpy(runtime.encode_image(
                image_batch([records.samples[i] for i in idx], task.spec(cfg), None)))
        else:
            latent, guide = runtime.encode_scan(records.pairs(idx)[0] if completion else octree)
            latent = torch.from_numpy(latent)
        if octree_decoder:
            for d, m in status_confusion(model, latent, octree, guide).items():
                confusion[d] = confusion.get(d, 0) + m
        scans = [records.scan(i) for i in idx] if keep_scan else None
        for i, frame, (pts, tree) in zip(idx, framing, decoded_points(model, latent, octree, resolution, seed,
                                                                      oracle, runtime and runtime.steps(), scans,
                                                                      fill_bias, guide)):
            sample = records.samples[i]
            pts = truth_view(sample, pts)
            row = {"category": sample.category, "shape_id": sample.shape_id,
                   "truth_nodes": int(sum(sample.octree.nodes_per_depth())), "output_points": int(len(pts)), **frame}
            truth = Reference(sample.points)
            if len(pts):
                near = truth.nearest(pts)
                threshold = fscore_threshold(truth.points)
                row["chamfer_x1e3"] = near.chamfer() * 1e3
                row["fscore"] = near.fscore(threshold)
                if align:       # the alignment is kept where it lowers the Chamfer distance
                    moved = truth.nearest(icp(pts, sample.points).apply(pts)) if len(pts) >= 3 else near
                    better = moved.chamfer() * 1e3 < row["chamfer_x1e3"]
                    row["chamfer_icp_x1e3"] = moved.chamfer() * 1e3 if better else row["chamfer_x1e3"]
                    row["fscore_icp"] = moved.fscore(threshold) if better else row["fscore"]
                if surfaces:
                    row.update(surface_rows(sample, truth, tree, max(len(pts), 1000), seed, threshold))
            else:
                empty += 1
                row.update({m: None for m in metrics if m != "mask_iou"})
            if sample.partial is not None:        # the do-nothing floor: the input itself
                row["input_chamfer_x1e3"] = truth.chamfer(sample.partial) * 1e3
                row.update(_missing(sample, pts))
            for m in metrics:
                if row.get(m) is not None:
                    per_cat[m].setdefault(sample.category, []).append(row[m])
            sizes["truth_nodes"].append(row["truth_nodes"])
            if tree is not None:
                row["decoded_nodes"] = int(sum(tree.nodes_per_depth()))
                sizes["decoded_nodes"].append(row["decoded_nodes"])
                sizes["decoded_leaves"].append(sum(tree.leaves_per_depth()))
                if mesh_dir and model.decoder.has_plane(tree.depth) and len(pts):
                    tree.normalizations = [sample.octree.normalizations[0]]
                    m = surface_mesh(tree, surface)
                    write_atomic(os.path.join(mesh_dir, f"{sample.shape_id}.ply"),
                                 trimesh.Trimesh(m.vertices, m.faces, process=False).export(file_type="ply"))
            per_shape.append(row)
    results = {
        "run": str(run), "task": cfg.task, "arch": cfg.arch, "depth": cfg.depth, "split": split,
        "resolution": resolution, "bundle": bundle, "shapes": len(per_shape), "empty_outputs": empty, "oracle": oracle,
        "per_category": per_category,
    }
    if photos:
        results["input"] = {"kind": "photos", "remove_background": remove_background,
                            "foreground_network": segment is not None and not exact_masks, "foreground": foreground,
                            "exact_masks": exact_masks,
                            "mask_sources": {k: sum(1 for r in per_shape if r["mask_source"] == k)
                                             for k in sorted({r["mask_source"] for r in per_shape})}}
    if surfaces:
        results["watertight_not_closed"] = sum(1 for r in per_shape if r.get("watertight_closed") is False)
    for m in metrics:
        means = {c: float(np.mean(v)) for c, v in sorted(per_cat[m].items())}
        results[m] = means
        results[f"{m}_category_mean"] = _mean_or_none(list(means.values()))
    results.update({
        "octree": {k: _mean_or_none(v) for k, v in sizes.items()},
        "status": {str(d): status_summary(m) for d, m in sorted(confusion.items())},
        "per_shape": per_shape,
        "seconds": time.perf_counter() - t,
    })
    if cfg.task == "image":
        results["encoder"] = cfg.encoder
    if completion:
        results["normals"] = normals
        results["keep_scan"] = keep_scan
        results["symmetry"] = symmetry
        results["keep_scan_empty_bias"] = {str(d): b for d, b in sorted((fill_bias or {}).items())}
    return results


def evaluate_classifier(model, cfg: TrainConfig, run: str, split: str = "test", limit: int | None = None,
                        batch_size: int = 16, runtime=None, bundle: str | None = None) -> dict:
    """Accuracy of a classifier (loaded by :func:`evaluate`): on each shape as built (rotation 0)
    and voted over the 12 rotations about the up axis (mean of the softmax), per category, with
    the confusion matrix.  ``runtime``: the exported bundle's onnxruntime sessions run instead of
    the torch model (``bundle`` is its folder, reported)."""

    task = TASKS[cfg.task]
    records = task.dataset(cfg, split, 0, limit=limit)
    t = time.perf_counter()
    probs = np.zeros((ROTATIONS, len(records), len(cfg.categories)))
    with torch.no_grad():
        for s in range(0, len(records), batch_size):
            idx = np.arange(s, min(len(records), s + batch_size))
            for k in range(ROTATIONS):
                octree, _ = records.batch(idx, k)
                probs[k, idx] = (runtime.classify(runtime.encode_octree(octree)) if runtime is not None else
                                 torch.softmax(model.logits(OctreeTensors.from_octree(octree)), 1).numpy())
    truth = records.labels
    single, voted = probs[0].argmax(1), probs.mean(0).argmax(1)
    per_rotation = (probs.argmax(2) == truth).mean(1)
    k = len(cfg.categories)
    confusion = np.bincount(truth * k + voted, minlength=k * k).reshape(k, k)
    per_cat = {c: {"shapes": int((truth == i).sum()),
                   "accuracy": float((single[truth == i] == i).mean()) if (truth == i).any() else None,
                   "voted_accuracy": float((voted[truth == i] == i).mean()) if (truth == i).any() else None}
               for i, c in enumerate(cfg.categories)}
    return {"run": str(run), "task": cfg.task, "arch": cfg.arch, "depth": cfg.depth, "split": split,
            "bundle": bundle, "shapes": len(records), "classes": cfg.categories,
            "accuracy": float((single == truth).mean()), "voted_accuracy": float((voted == truth).mean()),
            "accuracy_per_rotation": per_rotation.round(4).tolist(), "per_category": per_cat,
            "confusion": confusion.tolist(),
            "per_shape": [{"category": s.category, "shape_id": s.shape_id,
                           "predicted": cfg.categories[int(single[i])], "voted": cfg.categories[int(voted[i])]}
                          for i, s in enumerate(records.samples)],
            "seconds": time.perf_counter() - t}


def torch_segment(model, spec):
    """The foreground network of a loaded model in torch, as :meth:`export.runtime.Runtime.segment`
    runs its graph: an (H, W, 3) uint8 image to its object probability on the network's grid."""

    def segment(rgb: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            logits = model.net(torch.from_numpy(mask_input(rgb, spec)[None])).numpy()
        return mask_output(logits[0, 0])
    return segment


def foreground_in_torch(checkpoint: str) -> tuple:
    """A foreground network's checkpoint or run folder, in torch: (its ``segment`` function, as
    :func:`torch_segment`; its :class:`~model.image.mask.MaskSpec`, with the guided filter
    calibrated for it): the background removal of the bundle it would be exported into."""
    loaded = load_model(checkpoint)
    if loaded.config.task != "foreground":
        raise ValueError(f"--foreground {checkpoint} is a {loaded.config.task} model, not a foreground network")
    spec = TASKS["foreground"].spec(loaded.config, loaded.meta)
    return torch_segment(loaded.model, spec), spec


def mask_ious(photos: list, segment, spec) -> list[float]:
    """Mask IoU of each photo (a :class:`model.data.photos.Photo`) through the service's path
    (:func:`model.image.mask.object_mask` with ``segment`` and ``spec``), at its own resolution;
    0 where nothing is found."""

    out = []
    for photo in photos:
        try:
            ours = object_mask(photo.rgb, segment, spec) > 0.5
        except NoObjectError:
            ours = np.zeros(photo.mask.shape, bool)
        out.append(mask_iou(ours, photo.mask > 0.5))
    return out


def evaluate_foreground(model, cfg: TrainConfig, run: str, split: str = "test", limit: int | None = None,
                        runtime=None, bundle: str | None = None, meta: dict | None = None) -> dict:
    """Mask IoU of the foreground network on each shape's photo-like test view (a render on a
    held-out background, no alpha: :func:`model.data.photos.photo_split_view`), at the photo's own
    resolution, through the service's path (:func:`model.image.mask.object_mask`: the guided filter,
    clean-up, a second pass on a small object in a large photo; a photo where it finds nothing
    scores 0); per category and overall, with the share of photos above 0.9.  ``meta``: the run's
    provenance (its calibrated guided filter), for the network in torch."""

    spec = runtime.bundle.mask_spec() if runtime is not None else TASKS[cfg.task].spec(cfg, meta)
    segment = runtime.segment if runtime is not None else torch_segment(model, spec)
    records = TASKS[cfg.task].dataset(cfg, split, 0, limit=limit)
    t = time.perf_counter()
    views = [(s, photo_split_view(s.images, s.shape_id)) for s in records.samples]
    rows = [{"category": s.category, "shape_id": s.shape_id, "mask_iou": iou,
             "object_share": float((photo.mask > 0.5).mean()), "photo_size": list(photo.mask.shape)}
            for (s, photo), iou in zip(views, mask_ious([p for _, p in views], segment, spec))]
    ious = np.array([r["mask_iou"] for r in rows])
    per_cat = category_means([r["category"] for r in rows], list(ious))
    return {"run": str(run), "task": cfg.task, "arch": cfg.arch, "split": split, "bundle": bundle,
            "shapes": len(rows), "input": {"kind": "photos"}, "mask_spec": spec.to_dict(), "mask_iou": per_cat,
            "mask_iou_category_mean": float(np.mean(list(per_cat.values()))), "mask_iou_mean": float(ious.mean()),
            "mask_iou_median": float(np.median(ious)), "mask_iou_above_0.9": float((ious > 0.9).mean()),
            "per_shape": rows, "seconds": time.perf_counter() - t}


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
        if args.resolution < 2 or args.limit is not None and args.limit < 1:
            raise ValueError("--resolution must be at least 2 and --limit at least 1")
        results = evaluate(args.run, args.data, args.split, args.resolution, args.limit, args.mesh_dir,
                           oracle=args.oracle, align=args.icp, bundle=args.bundle, normals=args.normals,
                           surface=args.surface, photos=args.photos, remove_background=args.remove_background,
                           keep_scan=args.keep_scan, symmetry=MIN_SUPPORT if args.symmetry else None,
                           per_category=args.per_category, foreground=args.foreground,
                           exact_masks=args.exact_masks)
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
              f"(median {results['mask_iou_median']:.4f}; above 0.9: {results['mask_iou_above_0.9']:.1%})")
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
                 f" and {results['watertight_fscore_category_mean']:.3f}; {results['watertight_not_closed']} not closed)")
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
