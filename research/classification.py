"""Classification accuracy: each shape as built and voted over the 12 rotations about the up axis,
per category, with the confusion matrix; in torch or through a bundle."""

from __future__ import annotations

import time

import numpy as np
import torch

from model.nn.tensors import OctreeTensors
from model.octree.geometry import ROTATIONS
from model.train.config import TrainConfig
from model.train.tasks import TASKS


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
