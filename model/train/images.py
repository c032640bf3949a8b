"""Image batches for shape-from-a-single-image: a render per shape through the shared preprocessing.

Training takes a random view of each shape and, for a share of the samples, composites it onto a
random background (plain colour, gradient, noise, or another shape's render) before the same
:func:`model.preprocess.prepare_image` the service runs, so photos with a background are in
distribution.  Evaluation takes a fixed view per shape on the spec's plain background.
"""

from __future__ import annotations

import numpy as np

from ..data.render import composite
from ..data.shapes import stable_hash
from ..preprocess import ImageSpec, prepare_image
from .data import Sample


def eval_view(shape_id: str, views: int) -> int:
    """The view a shape is evaluated on: fixed per shape, spread over the views."""
    return stable_hash("eval-view", shape_id) % views


def random_background(rng: np.random.Generator, size: tuple[int, int], others: list[Sample]) -> np.ndarray:
    """(H, W, 3) uint8: a plain colour, gradient or noise (:func:`composite`), or another shape's
    render on a plain colour, randomly flipped and shifted."""
    h, w = size
    if others and rng.random() < 0.25:
        other = others[int(rng.integers(len(others)))]
        view = other.images[int(rng.integers(len(other.images)))]
        bg = composite(view, tuple(int(c) for c in rng.integers(0, 256, 3)))
        if rng.random() < 0.5:
            bg = bg[:, ::-1]
        bg = np.roll(bg, (int(rng.integers(-h // 2, h // 2)), int(rng.integers(-w // 2, w // 2))), axis=(0, 1))
        return _fit(bg, h, w)
    return composite(np.zeros((h, w, 4), np.uint8), rng=rng)


def _fit(img: np.ndarray, h: int, w: int) -> np.ndarray:
    """Tile or crop ``img`` to (h, w)."""
    reps = (-(-h // img.shape[0]), -(-w // img.shape[1]), 1)
    return np.tile(img, reps)[:h, :w]


def image_batch(samples: list[Sample], spec: ImageSpec, rng: np.random.Generator | None,
                background_share: float = 0.5, others: list[Sample] | None = None) -> np.ndarray:
    """Encoder inputs (B, 3, S, S) float32 of ``samples``: random views and backgrounds with
    ``rng``, each shape's :func:`eval_view` on the plain background without."""
    out = np.empty((len(samples), 3, spec.size, spec.size), np.float32)
    for i, s in enumerate(samples):
        if rng is None:
            out[i] = prepare_image(s.images[eval_view(s.shape_id, len(s.images))], spec)
            continue
        rgba = s.images[int(rng.integers(len(s.images)))]
        if rng.random() < background_share:
            bg = random_background(rng, rgba.shape[:2], others or [])
            a = rgba[..., 3:4].astype(np.float32) / 255.0
            rgb = np.round(rgba[..., :3] * a + bg * (1 - a)).astype(np.uint8)
            out[i] = prepare_image(rgb, spec)
        else:
            out[i] = prepare_image(rgba, spec)
    return out
