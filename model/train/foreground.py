"""Foreground-network training batches: photo-like composites of the renders and their exact masks.

Every sample is a random view of a shape placed on a random background by
:func:`model.data.photos.photo_composite`, made into the network's input by the same
:func:`model.image.mask.mask_input` the service runs; its target is the exact alpha, box-filtered
to the network's resolution.  A share of the samples (``crop_share``) is what a second look sees
(:func:`second_look`): the object's square cut from the photo and enlarged to the network's input.
Validation draws one fixed composite per shape (training backgrounds; the held-out photographs
are for the test split only).  A network trained for thin parts also gets each target's tubed
skeleton (:func:`tubed_skeletons`) for the skeleton recall loss.

The refinement network (:func:`refine_batch`) is trained on what it is served: larger photos
(:data:`REFINE_STYLE`), the first network's mask of each (the served first stage,
:func:`model.image.mask.object_mask`), and the object's square about that mask cut at its own
resolution (:func:`model.image.mask.crop_input`), its target the exact mask over the same square;
validation reports the recall of the thin parts (:func:`thin_parts`) apart.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage
from skimage.morphology import skeletonize

from ..data.photos import Photo, PhotoStyle, mask_box, photo_composite
from ..data.shapes import stable_hash
from ..image.mask import (
    MaskSpec,
    NoObjectError,
    crop_input,
    mask_bounds,
    mask_input,
    object_mask,
    object_square,
    refine_square,
    resize_mask,
)
from .data import Sample

BOX_ERROR = 0.1
"""The largest error of each edge of the first look's box, as a share of the box's longest side."""


def second_look(photo: Photo, rng: np.random.Generator, spec: MaskSpec) -> Photo:
    """What :func:`model.image.mask.object_mask`'s second look cuts from ``photo``: the square about
    the object's box (its edges moved by up to :data:`BOX_ERROR`, as a first look's mask places
    them), with ``spec.refine_margin``; ``photo`` itself when the object is not in it or the square
    covers ``spec.refine`` of the photo or more (no second look then)."""
    if photo.box is None:
        return photo
    h, w = photo.mask.shape
    top, left, bottom, right = photo.box
    error = np.round(rng.uniform(-BOX_ERROR, BOX_ERROR, 4) * max(bottom - top, right - left)).astype(int)
    top, left = top + int(error[0]), left + int(error[1])
    bottom, right = max(top + 1, bottom + int(error[2])), max(left + 1, right + int(error[3]))
    square = refine_square((top, left, bottom, right), h, w, spec)
    if square is None or square[1] - square[0] < 2 or square[3] - square[2] < 2:
        return photo
    y0, y1, x0, x1 = square
    mask = photo.mask[y0:y1, x0:x1]
    return Photo(np.ascontiguousarray(photo.rgb[y0:y1, x0:x1]), np.ascontiguousarray(mask), mask_box(mask))


def mask_batch(samples: list[Sample], spec: MaskSpec, rng: np.random.Generator | None,
               crop_share: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """(B, 3, S, S) network inputs and (B, 1, S, S) target coverage in [0, 1] of ``samples``, a
    ``crop_share`` of them second looks' views."""
    images = np.empty((len(samples), 3, spec.size, spec.size), np.float32)
    masks = np.empty((len(samples), 1, spec.size, spec.size), np.float32)
    for i, s in enumerate(samples):
        r = rng if rng is not None else np.random.default_rng(stable_hash("foreground-val", s.shape_id))
        photo = photo_composite(s.images[int(r.integers(len(s.images)))], r, "train")
        if crop_share > 0 and r.random() < crop_share:
            photo = second_look(photo, r, spec)
        images[i] = mask_input(photo.rgb, spec)
        masks[i, 0] = np.clip(resize_mask(photo.mask, spec.size, spec.size), 0, 1)
    return images, masks


def tubed_skeletons(masks: np.ndarray) -> np.ndarray:
    """The tubed skeletons of target masks (B, 1, S, S) in [0, 1]: each mask's object (coverage
    > 0.5) thinned to one-pixel lines (:func:`skimage.morphology.skeletonize`) and dilated by
    one pixel (a 3x3 cross), as float32 in {0, 1}; all zero for an image without the object.
    Every skeleton pixel lies on the object: the tube is cut to it."""
    out = np.zeros_like(masks, dtype=np.float32)
    cross = ndimage.generate_binary_structure(2, 1)
    for i, m in enumerate(masks[:, 0] > 0.5):
        if m.any():
            out[i, 0] = ndimage.binary_dilation(skeletonize(m), cross) & m
    return out


REFINE_STYLE = PhotoStyle(scale=(0.2, 0.95), short_side=(240, 800))
"""The photos the refinement network trains on: the object up to 760 pixels across, so that a
thin part of the render is several pixels wide in the photo, as in a user's photo."""
THIN = 0.02
"""A thin part: object pixels within this share of the object box's longest side of the
background (a wing, a leg, a rail; and every object's rim)."""


def thin_parts(masks: np.ndarray, boxes: list[tuple[int, int, int, int] | None] | None = None) -> np.ndarray:
    """(B, 1, S, S) float32 in {0, 1}: the pixels of each target mask (coverage > 0.5) within
    :data:`THIN` of its object box's longest side (``boxes``, default the mask's own) from the
    background, by the Euclidean distance transform."""
    out = np.zeros_like(masks, dtype=np.float32)
    for i, m in enumerate(masks[:, 0] > 0.5):
        box = mask_bounds(m) if boxes is None else boxes[i]
        if box is not None and m.any():
            side = max(box[2] - box[0], box[3] - box[1])
            out[i, 0] = (ndimage.distance_transform_edt(np.pad(m, 1))[1:-1, 1:-1] <= max(1.0, THIN * side)) & m
    return out


def refine_sample(photo: Photo, first_look, first_spec: MaskSpec, spec: MaskSpec,
                  rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """The refinement network's input (4, S, S) and target coverage (S, S) of one photo: the first
    stage's mask (``first_look`` and ``first_spec``, as served; where it finds nothing, an empty
    mask and the exact box with the errors of :data:`BOX_ERROR` tripled), the object's square
    about it, each edge of its box moved by up to a third of :data:`BOX_ERROR`."""
    h, w = photo.mask.shape
    try:
        first = object_mask(photo.rgb, first_look, first_spec)
        box, error = mask_bounds(first > 0.5), BOX_ERROR / 3
    except NoObjectError:
        first, box, error = np.zeros((h, w), np.float32), photo.box or (0, 0, h, w), 3 * BOX_ERROR
    top, left, bottom, right = box
    moved = np.round(rng.uniform(-error, error, 4) * max(bottom - top, right - left)).astype(int)
    top, left = int(np.clip(top + moved[0], 0, h - 1)), int(np.clip(left + moved[1], 0, w - 1))
    box = (top, left, max(top + 1, min(h, bottom + int(moved[2]))), max(left + 1, min(w, right + int(moved[3]))))
    y0, y1, x0, x1 = square = object_square(box, h, w, spec.crop_margin)
    target = resize_mask(photo.mask[y0:y1, x0:x1], spec.crop_size, spec.crop_size)
    return crop_input(photo.rgb, first, square, spec), np.clip(target, 0, 1)


def refine_batch(samples: list[Sample], first_look, first_spec: MaskSpec, spec: MaskSpec,
                 rng: np.random.Generator | None) -> tuple[np.ndarray, np.ndarray]:
    """(B, 4, S, S) refinement inputs and (B, 1, S, S) target coverage of ``samples``, one
    :data:`REFINE_STYLE` photo of a random view each (validation: fixed per shape)."""
    size = spec.crop_size
    images = np.empty((len(samples), 4, size, size), np.float32)
    masks = np.empty((len(samples), 1, size, size), np.float32)
    for i, s in enumerate(samples):
        r = rng if rng is not None else np.random.default_rng(stable_hash("refine-val", s.shape_id))
        photo = photo_composite(s.images[int(r.integers(len(s.images)))], r, "train", REFINE_STYLE)
        images[i], masks[i, 0] = refine_sample(photo, first_look, first_spec, spec, r)
    return images, masks
