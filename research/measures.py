"""The evaluation's measures of one shape and their summaries: Chamfer distance and F-score of
points and of both surfaces, completion's missing part, the subsets evaluated, the status
confusion's summary."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import trimesh

from model.octree import Octree
from model.octree.metrics import Reference, mean_squared_distance, missing_part
from model.surface import SURFACES, surface_mesh
from model.surface.crossing import crossing_faces
from model.train.completion import truth_view
from model.train.data import manifest_rows

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
    the truth, whether the closed one is closed and the share of its faces that cross or touch
    another (:func:`model.surface.crossing.crossing_faces`).  The surfaces are measured on ``count``
    points drawn uniformly at random by area (as many as the output's, at least 1,000): random
    draws leave gaps that a stratified protocol does not, so only draws of the same kind compare
    the two surfaces (the patches are measured both ways)."""
    row = {}
    for kind in SURFACES:
        m = surface_mesh(tree, kind, world=False)
        name = "watertight" if kind == "watertight" else "patches_area"
        if kind == "watertight":
            row["watertight_closed"] = m.closed
            row["watertight_crossing_share"] = float(crossing_faces(m.vertices, m.faces).mean()) if len(m.faces) else 0.0
        if not len(m.faces):
            row.update({f"{name}_chamfer_x1e3": None, f"{name}_fscore": None})
            continue
        drawn = trimesh.sample.sample_surface(trimesh.Trimesh(m.vertices, m.faces, process=False), count, seed=seed)[0]
        near = truth.nearest(truth_view(sample, drawn))
        row.update({f"{name}_chamfer_x1e3": near.chamfer() * 1e3, f"{name}_fscore": near.fscore(threshold)})
    return row


def missing_rows(sample, pts: np.ndarray) -> dict:
    """Completion rows: the missing part's distance to the output and to the input itself."""
    part = missing_part(sample.points, sample.partial, MISSING_GAP)
    if not len(part):
        return {"missing_x1e3": None, "input_missing_x1e3": None}
    return {"missing_x1e3": mean_squared_distance(part, pts) * 1e3 if len(pts) else None,
            "input_missing_x1e3": mean_squared_distance(part, sample.partial) * 1e3}


def mean_or_none(values: list[float]) -> float | None:
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
