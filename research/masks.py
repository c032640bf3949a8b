"""Foreground masks for evaluation: a foreground network in torch as the service runs its graph,
the mask IoU and the thin parts' recall of photos through the service's path, and the foreground
network's own evaluation."""

from __future__ import annotations

import time
from collections.abc import Callable

import numpy as np

from model.checkpoint import load_model
from model.data.photos import Photo, photo_split_view
from model.image.mask import MaskSpec, NoObjectError, mask_iou, object_mask
from model.networks.foreground import torch_segment
from model.train.config import TrainConfig
from model.train.foreground import thin_parts
from model.train.tasks import TASKS

from .results import category_means


def foreground_in_torch(checkpoint: str) -> tuple:
    """A foreground network's checkpoint or run folder, in torch: (its ``segment`` function, as
    :func:`model.networks.foreground.torch_segment`; its :class:`~model.image.mask.MaskSpec`, with the guided filter
    calibrated for it): the background removal of the bundle it would be exported into."""
    loaded = load_model(checkpoint)
    if loaded.config.task != "foreground":
        raise ValueError(f"--foreground {checkpoint} is a {loaded.config.task} model, not a foreground network")
    spec = TASKS["foreground"].spec(loaded.config, loaded.meta)
    return torch_segment(loaded.model.net, spec), spec


def thin_recall(ours: np.ndarray, photo: Photo) -> float:
    """The share of the photo's thin-part pixels (:func:`model.train.foreground.thin_parts` of its
    exact mask and box) that the boolean mask ``ours`` keeps; 1.0 when it has none."""
    thin = thin_parts(photo.mask[None, None].astype(np.float32), [photo.box])[0, 0] > 0
    return float((ours & thin).sum() / thin.sum()) if thin.any() else 1.0


def photo_masks(photos: list[Photo], segment: Callable[[np.ndarray], np.ndarray], spec: MaskSpec,
                refine: Callable[[np.ndarray], np.ndarray] | None = None) -> list[np.ndarray]:
    """The boolean object mask of each photo (a :class:`model.data.photos.Photo`) through the
    service's path (:func:`model.image.mask.object_mask` with ``segment``, ``spec`` and the
    refinement network ``refine``, if any), at its own resolution; empty where nothing is found."""
    out = []
    for photo in photos:
        try:
            out.append(object_mask(photo.rgb, segment, spec, refine) > 0.5)
        except NoObjectError:
            out.append(np.zeros(photo.mask.shape, bool))
    return out


def mask_ious(photos: list, segment, spec) -> list[float]:
    """Mask IoU of each photo through the service's path (:func:`photo_masks`); 0 where nothing is found."""
    return [mask_iou(ours, photo.mask > 0.5) for ours, photo in zip(photo_masks(photos, segment, spec), photos)]


def evaluate_foreground(model, cfg: TrainConfig, run: str, split: str = "test", limit: int | None = None,
                        runtime=None, bundle: str | None = None, meta: dict | None = None) -> dict:
    """Mask IoU of the foreground network on each shape's photo-like test view (a render on a
    held-out background, no alpha: :func:`model.data.photos.photo_split_view`), at the photo's own
    resolution, through the service's path (:func:`model.image.mask.object_mask`: the guided filter,
    clean-up, a second pass on a small object in a large photo, the bundle's refinement network
    when it has one; a photo where it finds nothing scores 0); per category and overall, with the
    share of photos above 0.9, and the thin parts' recall (:func:`thin_recall`) likewise.  ``meta``: the run's
    provenance (its calibrated guided filter), for the network in torch."""

    spec = runtime.bundle.mask_spec() if runtime is not None else TASKS[cfg.task].spec(cfg, meta)
    segment = runtime.segment if runtime is not None else torch_segment(model.net, spec)
    refine = runtime.refine if runtime is not None and runtime.has_refine else None
    records = TASKS[cfg.task].dataset(cfg, split, 0, limit=limit)
    t = time.perf_counter()
    views = [(s, photo_split_view(s.images, s.shape_id)) for s in records.samples]
    masks = photo_masks([p for _, p in views], segment, spec, refine)
    rows = [{"category": s.category, "shape_id": s.shape_id, "mask_iou": mask_iou(ours, photo.mask > 0.5),
             "thin_recall": thin_recall(ours, photo), "object_share": float((photo.mask > 0.5).mean()),
             "photo_size": list(photo.mask.shape)} for (s, photo), ours in zip(views, masks)]
    ious, thin = np.array([r["mask_iou"] for r in rows]), [r["thin_recall"] for r in rows]
    per_cat = category_means([r["category"] for r in rows], list(ious))
    thin_cat = category_means([r["category"] for r in rows], thin)
    return {"run": str(run), "task": cfg.task, "arch": cfg.arch, "split": split, "bundle": bundle,
            "refined": refine is not None, "shapes": len(rows), "input": {"kind": "photos"},
            "mask_spec": spec.to_dict(), "mask_iou": per_cat,
            "mask_iou_category_mean": float(np.mean(list(per_cat.values()))), "mask_iou_mean": float(ious.mean()),
            "mask_iou_median": float(np.median(ious)), "mask_iou_above_0.9": float((ious > 0.9).mean()),
            "thin_recall": thin_cat, "thin_recall_category_mean": float(np.mean(list(thin_cat.values()))),
            "thin_recall_mean": float(np.mean(thin)), "per_shape": rows, "seconds": time.perf_counter() - t}
