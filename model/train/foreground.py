"""Foreground-network training batches: photo-like composites of the renders and their exact masks.

Every sample is a random view of a shape placed on a random background by
:func:`model.data.photos.photo_composite`, made into the network's input by the same
:func:`model.preprocess.mask_input` the service runs; its target is the exact alpha, box-filtered
to the network's resolution.  Validation draws one fixed composite per shape (training
backgrounds; the held-out photographs are for the test split only).
"""

from __future__ import annotations

import numpy as np

from ..data.photos import photo_composite
from ..data.shapes import stable_hash
from ..preprocess import MaskSpec, mask_input, resize_mask
from .data import Sample


def mask_batch(samples: list[Sample], spec: MaskSpec, rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3, S, S) network inputs and (B, 1, S, S) target coverage in [0, 1] of ``samples``."""
    images = np.empty((len(samples), 3, spec.size, spec.size), np.float32)
    masks = np.empty((len(samples), 1, spec.size, spec.size), np.float32)
    for i, s in enumerate(samples):
        r = rng if rng is not None else np.random.default_rng(stable_hash("foreground-val", s.shape_id))
        photo = photo_composite(s.images[int(r.integers(len(s.images)))], r, "train")
        images[i] = mask_input(photo.rgb, spec)
        masks[i, 0] = np.clip(resize_mask(photo.mask, spec.size, spec.size), 0, 1)
    return images, masks
