"""The decode loop: grow an octree level by level from a decoder's predictions.

Written once against :class:`DecoderSteps`, which a torch module (evaluation) and an ONNX Runtime
session (the service) both satisfy; the octree bookkeeping (keys, labels, neighbour tables) is
the NumPy octree core's.  No torch here.
"""

from __future__ import annotations

import dataclasses
import functools
from collections.abc import Mapping
from typing import Any, Protocol

import numpy as np

from .octree import EMPTY, LEAF, SPLIT, Normalization, Octree, OctreeLevel
from .octree import keys as morton
from .octree.neighbors import child_neighbors, root_neighbors

DECODED_NORMALIZATION = Normalization(center=np.zeros(3), scale=1.0)
"""Decoded octrees live in the unit cube; this maps it to a cube of edge 1 centred at 0."""


class DecoderSteps(Protocol):
    """What the loop needs from a decoder, one depth at a time (features stay opaque)."""

    depth: int

    def classes(self, depth: int) -> int:
        """2 (empty / non-empty) or 3 (empty / poorly approximated = split / well approximated = leaf)."""

    def start(self, latent: np.ndarray) -> Any:
        """Features of the depth-2 octants (64 per shape, in key order) from latent codes (B, L)."""

    def predict(self, depth: int, features: Any, neighbors: np.ndarray, skip: Any = None,
                skip_index: np.ndarray | None = None) -> tuple[Any, np.ndarray, np.ndarray | None]:
        """Features after the depth's convolutions, status logits (N, classes) and planes
        (N, 4: unit normal, d* in [-1, 1]) or None for decoders without planes.  A guided
        decoder also takes the encoder's features of the depth (``skip``) and each octant's row
        in them (``skip_index``, see :class:`Guide`)."""

    def expand(self, depth: int, features: Any, split: np.ndarray) -> Any:
        """Features of the children (8 per split octant, in slot order) of octants ``split``."""


@dataclasses.dataclass
class Guide:
    """What a guided decoder (output-guided skip connections) reads of its input, per depth d
    from the full depth: the input octree's keys (ascending, batch bits = the shape's position
    in the decoded batch) and the encoder's features of those octants (opaque: torch or NumPy).

    Invariant: ``len(keys[d]) == len(features[d])`` and both cover the same depths."""

    keys: dict[int, np.ndarray]
    features: dict[int, Any]

    @classmethod
    def of(cls, octree: Octree, features: Mapping[int, Any]) -> Guide:
        """The guide of a (batched) input octree and its encoder's per-depth features."""
        return cls({d: octree.levels[d].key for d in features}, dict(features))

    def rows(self, depth: int, keys: np.ndarray) -> np.ndarray:
        """Each key's row in the depth's features (the row count where the input has no octant)."""
        return morton.lookup(self.keys[depth], keys)

    def matched(self, target: Octree) -> dict[int, tuple[Any, np.ndarray]]:
        """Per depth, the features and each ``target`` octant's row in them (teacher forcing)."""
        return {d: (f, self.rows(d, target.levels[d].key)) for d, f in self.features.items()}

    def subset(self, shapes: np.ndarray) -> Guide:
        """The guide of shapes ``shapes`` (ascending positions) of the batch, renumbered 0.."""
        shapes = np.asarray(shapes, dtype=np.int64)
        keys, features = {}, {}
        for d, k in self.keys.items():
            batch = morton.batch_of(k)
            rows = np.flatnonzero(np.isin(batch, shapes))
            keys[d] = morton.with_batch(k[rows], np.searchsorted(shapes, batch[rows]))
            features[d] = self.features[d][rows]
        return Guide(keys, features)


def matched_rows(source: Octree, target: Octree) -> dict[int, np.ndarray]:
    """Per depth from the full depth, each ``target`` octant's row among ``source``'s octants of
    the same depth, matched by key (:func:`model.octree.keys.lookup`): what a guided decoder
    trained on ``target`` reads of the encoder's features of ``source``."""
    return {d: morton.lookup(source.levels[d].key, target.levels[d].key)
            for d in range(source.full_depth, min(source.depth, target.depth) + 1)}


def full_levels(batch_size: int, full_depth: int = 2) -> list[OctreeLevel]:
    """Depths 0..full_depth of ``batch_size`` shapes, every octant split down to full_depth.

    Fresh arrays on every call (callers may modify them), copied from a per-size template.
    """
    return [dataclasses.replace(lv, **{f: np.copy(getattr(lv, f)) for f in _ARRAYS})
            for lv in _full_levels(batch_size, full_depth)]


_ARRAYS = ("key", "label", "child", "parent", "plane", "error", "npoints", "neighbors")


@functools.lru_cache(maxsize=16)
def _full_levels(batch_size: int, full_depth: int) -> tuple[OctreeLevel, ...]:
    levels = []
    for d in range(full_depth + 1):
        side = 1 << d
        grid = np.stack(np.meshgrid(*[np.arange(side)] * 3, indexing="ij"), -1).reshape(-1, 3)
        shape_keys = np.sort(morton.encode(grid))
        batch_bits = np.arange(batch_size, dtype=np.uint64)[:, None] << np.uint64(morton.BATCH_SHIFT)
        key = (shape_keys[None] | batch_bits).ravel()
        n = len(key)
        last = d == full_depth
        levels.append(_level(d, key, parent=np.repeat(np.arange(n // 8, dtype=np.int32), 8) if d
                             else np.full(n, -1, np.int32)))
        if not last:
            levels[-1].label[:] = SPLIT
            levels[-1].child = np.arange(n, dtype=np.int32)
    levels[0].neighbors = root_neighbors(batch_size)
    for d in range(1, full_depth + 1):
        levels[d].neighbors = child_neighbors(levels[d - 1].neighbors, levels[d - 1].child)
    return tuple(levels)


def _level(depth: int, key: np.ndarray, parent: np.ndarray) -> OctreeLevel:
    """A level of empty octants with the given keys and parents."""
    n = len(key)
    return OctreeLevel(depth=depth, key=key, label=np.zeros(n, np.int8), child=np.full(n, -1, np.int32),
                       parent=parent, plane=np.zeros((n, 4), np.float32),
                       error=np.full(n, np.nan, np.float32), npoints=np.zeros(n, np.int32))


def empty_bias_of(keep_scan: Any) -> dict[int, float]:
    """The ``empty_bias`` of a recorded keep_scan setting (``{"empty_bias": {"5": 2.0, ...}, ...}``:
    a checkpoint's model.json ``keep_scan``, a bundle manifest's ``output.keep_scan``); {} for
    none.  ValueError if it is not a mapping of depths to finite numbers."""
    bias = (keep_scan or {}).get("empty_bias", {}) if isinstance(keep_scan, (dict, type(None))) else None
    if not isinstance(bias, dict) or not all(
            str(d).isdigit() and isinstance(b, (int, float)) and np.isfinite(b) for d, b in bias.items()):
        raise ValueError("keep_scan.empty_bias must map depths to numbers")
    return {int(d): float(b) for d, b in bias.items()}


def status_to_labels(logits: np.ndarray, classes: int, last: bool) -> np.ndarray:
    """Octree labels from status logits: non-empty splits (or is a leaf at the max depth)."""
    status = np.argmax(logits, axis=1)
    if classes == 2:
        label = np.where(status == 1, LEAF if last else SPLIT, EMPTY)
    else:
        label = np.choose(status, [EMPTY, SPLIT, LEAF])
        if last:
            label = np.where(label == SPLIT, LEAF, label)
    return label.astype(np.int8)


def decode(steps: DecoderSteps, latent: np.ndarray, full_depth: int = 2,
           adaptive_depth: int = 4, empty_bias: Mapping[int, float] | None = None,
           guide: Guide | None = None) -> Octree:
    """Grow the octree of each latent code (B, L) down to ``steps.depth``.

    Every octant's status decides whether it is empty, a leaf with its predicted patch, or split;
    split octants hand their features to their 8 children.  ``empty_bias`` (depth -> bias) is
    added to the empty class's logit at those depths: a positive bias keeps only the octants the
    decoder is surer of (a completion fused with its scan uses it, see
    :func:`model.octree.fuse.keep_scan`).  ``guide``: the input of a guided decoder (its octants
    matched to the grown ones by key at every depth).  Returns a batched :class:`Octree` in unit-cube
    coordinates (see :data:`DECODED_NORMALIZATION`).
    """
    empty_bias = dict(empty_bias or {})
    latent = np.asarray(latent)
    batch = len(latent)
    levels = full_levels(batch, full_depth)
    features = steps.start(latent)
    for d in range(full_depth, steps.depth + 1):
        lv = levels[d]
        skip = () if guide is None else (guide.features[d], guide.rows(d, lv.key))
        features, logits, planes = steps.predict(d, features, lv.neighbors, *skip)
        if empty_bias.get(d):
            logits = np.array(logits, dtype=np.float32)
            logits[:, EMPTY] += empty_bias[d]
        last = d == steps.depth
        lv.label = status_to_labels(np.asarray(logits), steps.classes(d), last)
        filled = lv.label != EMPTY
        if planes is not None:
            lv.plane = np.where(filled[:, None], np.asarray(planes, dtype=np.float32), 0.0).astype(np.float32)
        split = np.flatnonzero(lv.label == SPLIT)
        lv.child = np.full(len(lv), -1, np.int32)
        lv.child[split] = np.arange(len(split), dtype=np.int32)
        if last:
            break
        key = morton.child_keys(lv.key[split])
        nxt = _level(d + 1, key, parent=np.repeat(split.astype(np.int32), 8))
        nxt.neighbors = child_neighbors(lv.neighbors, lv.child)
        levels.append(nxt)
        if len(split) == 0:          # nothing left to refine: the deeper levels stay empty
            for e in range(d + 2, steps.depth + 1):
                empty = _level(e, np.zeros(0, np.uint64), np.zeros(0, np.int32))
                empty.neighbors = np.zeros((0, 27), np.int32)
                levels.append(empty)
            break
        features = steps.expand(d, features, split)
    return Octree(depth=steps.depth, levels=levels, adaptive=steps.classes(steps.depth) == 3,
                  threshold=float("nan"), full_depth=full_depth, adaptive_depth=adaptive_depth,
                  normalizations=[DECODED_NORMALIZATION] * batch)
