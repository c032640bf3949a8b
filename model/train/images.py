"""Image batches for shape-from-a-single-image: a render per shape through the shared preprocessing.

Training takes a random view of each shape and, for a share of the samples, composites it onto a
random background (plain colour, gradient, noise, or another shape's render) before the same
:func:`model.image.frame.prepare_image` the service runs, so photos with a background are in
distribution; another share is made a photo (an object on a real or procedural scene, no alpha) and
brought back through the service's background removal with an imperfect mask.  Evaluation takes a
fixed view per shape on the spec's plain background.
"""

from __future__ import annotations

import numpy as np

from ..data.photos import ENCODER_STYLE, box_prompt, imperfect_mask, photo_composite, photo_split_view, with_alpha
from ..data.render import composite
from ..data.shapes import stable_hash
from ..image.frame import Framed, ImageSpec, frame_object, prepare_image, region_of
from ..image.mask import MaskSpec, NoObjectError, mask_iou
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
                background_share: float = 0.5, others: list[Sample] | None = None,
                views: np.ndarray | None = None, photo_share: float = 0.0) -> np.ndarray:
    """Encoder inputs (B, 3, S, S) float32 of ``samples``: with ``rng``, views ``views`` (default
    random), a share ``photo_share`` of them made photos (:func:`photo_input`), a share
    ``background_share`` of the rest on random backgrounds; without, each shape's
    :func:`eval_view` on the plain background."""
    out = np.empty((len(samples), 3, spec.size, spec.size), np.float32)
    for i, s in enumerate(samples):
        if rng is None:
            out[i] = prepare_image(s.images[eval_view(s.shape_id, len(s.images))], spec)
            continue
        rgba = s.images[int(rng.integers(len(s.images))) if views is None else int(views[i])]
        if rng.random() < photo_share:
            out[i] = photo_input(rgba, spec, rng)
        elif rng.random() < background_share:
            bg = random_background(rng, rgba.shape[:2], others or [])
            a = rgba[..., 3:4].astype(np.float32) / 255.0
            rgb = np.round(rgba[..., :3] * a + bg * (1 - a)).astype(np.uint8)
            out[i] = prepare_image(rgb, spec)
        else:
            out[i] = prepare_image(rgba, spec)
    return out


def photo_input(rgba: np.ndarray, spec: ImageSpec, rng: np.random.Generator) -> np.ndarray:
    """The encoder input of a render made a photo (:func:`photo_composite`) and brought back through
    the service's path (:func:`frame_object`) with an imperfect mask in place of the foreground
    network's, framed at a jittered foreground ratio."""
    photo = photo_composite(rgba, rng, "train", ENCODER_STYLE)
    mask = imperfect_mask(photo.mask, rng)
    ratio = min(1.0, spec.foreground_ratio * rng.uniform(0.9, 1.08))
    try:
        return frame_object(photo.rgb, spec, segment=lambda _: mask, foreground_ratio=ratio,
                            mask_spec=MaskSpec(refine=0.0)).image           # the mask stands for the final one
    except NoObjectError:                # the degraded mask lost the object: the plain render instead
        return prepare_image(rgba, spec)


def frame_or_whole(rgb: np.ndarray, spec: ImageSpec, segment=None, remove_background: str = "auto",
                   mask_spec: MaskSpec = MaskSpec(), region: tuple[int, int, int, int] | None = None) -> Framed:
    """:func:`frame_object` (``region``: a box prompt, top, left, bottom, right), or where it finds
    no object (the service answers 422 there) the photo framed without a mask (the region its
    crop), its ``mask_source`` "missed": how evaluations and benchmarks go on."""
    try:
        return frame_object(rgb, spec, segment, remove_background, mask_spec=mask_spec, region=region)
    except NoObjectError:
        framed = frame_object(rgb, spec, None, "false", region=region)
        framed.mask_source = "missed"
        return framed


def photo_batch(samples: list[Sample], spec: ImageSpec, segment=None, remove_background: str = "auto",
                mask_spec: MaskSpec = MaskSpec(), exact_masks: bool = False, box_prompts: bool = False
                ) -> tuple[np.ndarray, list[dict]]:
    """Encoder inputs (B, 3, S, S) of each shape's fixed photo-like test view
    (:func:`photo_split_view`) through :func:`frame_or_whole` with ``segment`` (the foreground
    network, or None), and per shape what was done: the mask's source, its IoU with the exact
    mask (None without a mask, 0 when the network found nothing), the crop box.
    ``exact_masks``: a diagnostic, each photo sent with its exact mask as its alpha channel (what a
    perfect foreground network would give; the mask's source is then "alpha").  ``box_prompts``:
    each photo sent with a box prompt about its object, as a user drags one
    (:func:`model.data.photos.box_prompt`)."""
    out = np.empty((len(samples), 3, spec.size, spec.size), np.float32)
    info = []
    for i, s in enumerate(samples):
        photo = photo_split_view(s.images, s.shape_id)
        image = photo.rgb
        if exact_masks:
            image = with_alpha(photo.rgb, photo.mask)
        box = box_prompt(photo.mask) if box_prompts else None
        region = None if box is None else region_of(box, photo.mask.shape, photo.mask.shape)
        framed = frame_or_whole(image, spec, segment, remove_background, mask_spec, region)
        out[i] = framed.image
        iou = None
        if framed.mask is not None:
            iou = mask_iou(framed.mask > 127, photo.mask > 0.5)
        elif framed.mask_source == "missed":
            iou = 0.0
        info.append({"mask_source": framed.mask_source, "mask_iou": iou, "box": framed.box,
                     "photo_size": list(photo.rgb.shape[:2])})
    return out, info
