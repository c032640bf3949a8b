"""Evaluation results as ``python -m research.evaluate`` writes them: per-category means, and the
results of one model on several splits of a dataset joined into one (a held-out seed's 780 shapes
are evaluated split by split).

A result is a dict whose ``per_shape`` rows (``category``, ``shape_id`` and a value per measure,
None where the output was empty) are the truth; every per-category dict ``result[m]`` and its
``result[m + "_category_mean"]`` (the mean of the categories' means) are derived from them.
"""

from __future__ import annotations

import math

import numpy as np

SETTINGS = ("run", "task", "arch", "depth", "resolution", "bundle", "oracle", "normals", "keep_scan", "symmetry",
            "keep_scan_empty_bias", "input")
"""What must be the same in results that are joined: the model, how it ran, on what input."""


def category_means(categories: list[str], values: list[float]) -> dict[str, float]:
    """The mean of ``values`` per category (``categories[i]`` is ``values[i]``'s), sorted by name."""
    by: dict[str, list[float]] = {}
    for c, v in zip(categories, values):
        by.setdefault(c, []).append(v)
    return {c: float(np.mean(by[c])) for c in sorted(by)}


def finite(value) -> bool:
    """Whether ``value`` is a measured number (not None, a flag, NaN or infinite)."""
    return isinstance(value, (int, float)) and not isinstance(value, bool) and math.isfinite(value)


def _setting(result: dict, key: str):
    """A setting of ``result`` as compared when joining: the photos' input without its counts."""
    value = result.get(key)
    if key == "input" and isinstance(value, dict):
        return {k: v for k, v in value.items() if k != "mask_sources"}
    return value


def join_results(results: list[dict]) -> dict:
    """One result holding the shapes of all ``results`` (the same model and settings on disjoint
    shapes, e.g. the splits of one dataset): rows concatenated, every per-category measure and its
    category mean recomputed from the rows, counts added, mean octree sizes over all shapes.  The
    confusion of the decoder's statuses is not joined (left out).  ValueError if the results differ
    in a setting (:data:`SETTINGS`) or share a shape."""
    if not results:
        raise ValueError("nothing to join")
    first = results[0]
    for r in results[1:]:
        differ = [k for k in SETTINGS if _setting(r, k) != _setting(first, k)]
        if differ:
            raise ValueError(f"results to join differ in {', '.join(differ)}")
    rows = [row for r in results for row in r["per_shape"]]
    keys = [(row["category"], row["shape_id"]) for row in rows]
    if len(set(keys)) != len(keys):
        raise ValueError("results to join share shapes: give each split once")
    if first.get("task") == "foreground":
        raise ValueError("the foreground network's results (mask IoU) are not joined: evaluate the photos at once")
    joined = {k: first[k] for k in SETTINGS if k in first}
    if isinstance(first.get("input"), dict) and "mask_sources" in first["input"]:    # photos: where masks came from
        sources = [r["input"].get("mask_sources", {}) for r in results]
        joined["input"] = {**first["input"], "mask_sources": {
            k: sum(s.get(k, 0) for s in sources) for k in sorted({k for s in sources for k in s})}}
    joined["split"] = "+".join(str(r.get("split")) for r in results)
    for count in ("shapes", "empty_outputs", "watertight_not_closed", "watertight_crossing"):
        if all(count in r for r in results):                  # a count some results lack is not summed
            joined[count] = sum(int(r.get(count) or 0) for r in results)
    for m in [k[:-len("_category_mean")] for k in first if k.endswith("_category_mean")]:
        kept = [row for row in rows if finite(row.get(m))]
        joined[m] = category_means([row["category"] for row in kept], [row[m] for row in kept])
        joined[f"{m}_category_mean"] = float(np.mean(list(joined[m].values()))) if kept else None
    sizes = {}
    for k in ("truth_nodes", "decoded_nodes", "decoded_leaves"):
        weighted = [(r["octree"][k], r.get("shapes", len(r["per_shape"]))) for r in results
                    if finite(r.get("octree", {}).get(k))]
        total = sum(n for _, n in weighted)
        sizes[k] = sum(v * n for v, n in weighted) / total if total else None
    joined["octree"] = sizes
    joined["per_shape"] = rows
    joined["seconds"] = sum(float(r.get("seconds") or 0.0) for r in results)
    return joined
