"""Framing for shape-from-a-single-image, one function for training and serving: the object
found (alpha, the border colour, or the foreground network's mask), cut out, composited or kept
on its background, cropped to its box, padded to a square, resized and normalised, so that
training, evaluation, export and the service all give the encoder identical tensors."""

from __future__ import annotations

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
from PIL import Image

from ..octree.jit import compiled
from .decode import MAX_PIXELS_DEFAULT, ImageError, decode_image
from .mask import (
    MaskSpec,
    NoObjectError,
    clean_mask,
    grown_box,
    mask_bounds,
    mask_confidence,
    mask_input,
    object_mask,
    spec_from_dict,
)


@dataclass(frozen=True)
class ImageSpec:
    """How an encoder expects its image: ``size`` x ``size`` RGB, channel-wise normalised.

    ``background``: the RGB colour transparent pixels are composited onto. ``margin``: the share of
    the square's side left empty around the object's crop box (on each side; the object's longest
    side fills ``foreground_ratio = 1 - 2 margin`` of the square). ``border_tolerance``:
    how far (0-255, max over channels) a pixel may differ from the border colour and still count as
    background when an opaque image is cropped.
    """

    size: int = 128
    mean: tuple[float, float, float] = (0.5, 0.5, 0.5)
    std: tuple[float, float, float] = (0.25, 0.25, 0.25)
    background: tuple[int, int, int] = (255, 255, 255)
    margin: float = 0.05
    border_tolerance: int = 24

    @property
    def foreground_ratio(self) -> float:
        return 1.0 - 2.0 * self.margin

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ImageSpec:
        return spec_from_dict(cls, d)


def object_box(rgba: np.ndarray, tolerance: int = 24) -> tuple[int, int, int, int] | None:
    """(top, left, bottom, right), exclusive, of the object: opaque pixels where the image has
    transparency, else pixels that differ from the border's median colour by more than
    ``tolerance`` in some channel; None when no pixel qualifies (fully transparent, or a flat image)."""
    alpha = rgba[..., 3]
    if alpha.min() < 250:
        return mask_bounds(alpha >= 128)
    rgb = rgba[..., :3]
    border = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
    twice = (2 * np.median(border, axis=0)).astype(np.int64)     # exact: the median is whole or a half
    top, left, bottom, right = _differing_bounds(rgba, twice, 2.0 * float(np.float32(tolerance)))
    return None if bottom == 0 else (top, left, bottom, right)


@compiled
def _differing_bounds(rgba: np.ndarray, twice_ref: np.ndarray, twice_tol: float) -> tuple[int, int, int, int]:
    """The bounds (top, left, bottom, right; exclusive; all 0 when none) of the pixels with
    ``|2 c - twice_ref| > twice_tol`` in some colour channel ``c``: ``|c - ref| > tol`` in whole
    numbers (float32 gives the same comparison exactly: the differences are halves below 256)."""
    h, w = rgba.shape[0], rgba.shape[1]
    top, left, bottom, right = h, w, 0, 0
    for y in range(h):
        first, last = -1, -1
        for x in range(w):
            for c in range(3):
                if abs(2 * np.int64(rgba[y, x, c]) - twice_ref[c]) > twice_tol:
                    if first < 0:
                        first = x
                    last = x
                    break
        if first >= 0:
            top = min(top, y)
            bottom = y + 1
            left = min(left, first)
            right = max(right, last + 1)
    if bottom == 0:
        return 0, 0, 0, 0
    return top, left, bottom, right


def as_rgba(image: np.ndarray) -> np.ndarray:
    """An (H, W, 4) uint8 image of an (H, W, 3|4) uint8 one (opaque alpha added); ImageError else."""
    image = np.asarray(image)
    if image.ndim != 3 or image.shape[2] not in (3, 4) or image.dtype != np.uint8:
        raise ImageError(f"expected an (H, W, 3|4) uint8 image, got {image.dtype} {image.shape}")
    if image.shape[2] == 3:
        image = np.concatenate([image, np.full(image.shape[:2] + (1,), 255, np.uint8)], axis=2)
    return image


def prepare_image(rgba: np.ndarray, spec: ImageSpec, keep_background: bool = False,
                  foreground_ratio: float | None = None, box: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """The encoder's input (3, size, size) float32 from an RGBA (or RGB) uint8 image.

    Transparent pixels are composited onto ``spec.background`` (``keep_background`` keeps the
    image's own colour under them instead).  The crop is the :func:`object_box`, or the whole image
    where it finds nothing (a fully transparent image is an ImageError: there is no object); the
    crop is grown to a square the object's longest side fills ``foreground_ratio`` of (default the
    spec's, ``1 - 2 spec.margin``) (taking the image's own surroundings,
    beyond its border the background colour or, for an opaque image, its edge pixels), resized with
    a box filter (antialiasing) and normalised by ``spec.mean`` / ``spec.std``.
    """
    rgba = as_rgba(rgba)
    if rgba[..., 3].max() == 0:
        raise ImageError("the image is fully transparent: there is no object to reconstruct")
    if box is None:
        box = object_box(rgba, spec.border_tolerance)
    h, w = rgba.shape[:2]
    top, left, bottom, right = box if box is not None else (0, 0, h, w)
    side = max(bottom - top, right - left)
    ratio = spec.foreground_ratio if foreground_ratio is None else foreground_ratio
    if not 0.05 <= ratio <= 1:
        raise ImageError(f"foreground_ratio must be in 0.05..1, got {ratio}")
    full = side + 2 * int(round(side * (1 - ratio) / 2 / ratio))
    y0 = top - (full - (bottom - top)) // 2            # the square around the crop, image coordinates
    x0 = left - (full - (right - left)) // 2
    ys, ye, xs, xe = max(0, y0), min(h, y0 + full), max(0, x0), min(w, x0 + full)
    part = rgba[ys:ye, xs:xe]                           # only the square's pixels are converted
    opaque = keep_background or rgba[..., 3].min() >= 250
    unchanged = keep_background or part[..., 3].min() == 255     # compositing would change nothing
    pads = ((ys - y0, y0 + full - ye), (xs - x0, x0 + full - xe))
    if opaque:
        # an opaque photo: the real surroundings, the image's edges extended beyond its border
        img = _edge_padded(part if unchanged else composite(part, spec.background), *pads)
    else:
        canvas = np.empty((full, full, 3), np.uint8)
        (pt, pb), (pl, pr) = pads
        background = np.asarray(spec.background, np.uint8)
        canvas[:pt], canvas[full - pb:] = background, background          # only the margins are filled
        canvas[pt:full - pb, :pl], canvas[pt:full - pb, full - pr:] = background, background
        inside = canvas[pt:full - pb, pl:full - pr]
        if unchanged:
            inside[:] = part[..., :3]
        else:
            composite(part, spec.background, inside)
        img = Image.fromarray(canvas, "RGB")
    img = img.resize((spec.size, spec.size), Image.Resampling.BOX if full >= spec.size else Image.Resampling.BILINEAR)
    x = np.asarray(img, np.float32) / 255.0
    x = (x - np.asarray(spec.mean, np.float32)) / np.asarray(spec.std, np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1))


def _edge_padded(image: np.ndarray, rows: tuple[int, int], cols: tuple[int, int]) -> Image.Image:
    """``np.pad(image[..., :3], (rows, cols, (0, 0)), mode="edge")`` as a Pillow RGB image: the
    edge rows and columns extended (the corners take the corner pixels).  An RGBA ``image`` is
    padded a whole pixel (4 bytes, one uint32) at a time and Pillow drops its alpha: np.pad of its
    colour channels, a strided view, takes 5x as long."""
    four = image.shape[2] == 4
    if four and image.strides[2] != 1:
        image = np.ascontiguousarray(image)
    pixels = image.view(np.uint32)[..., 0] if four else image
    (pt, pb), (pl, pr) = rows, cols
    h, w = pixels.shape[:2]
    out = np.empty((h + pt + pb, w + pl + pr) + pixels.shape[2:], pixels.dtype)
    band = out[pt:pt + h]
    band[:, pl:pl + w] = pixels
    band[:, :pl] = pixels[:, :1]
    band[:, pl + w:] = pixels[:, -1:]
    out[:pt] = band[:1]
    out[pt + h:] = band[-1:]
    if four:
        return Image.fromarray(out.view(np.uint8).reshape(out.shape + (4,)), "RGBA").convert("RGB")
    return Image.fromarray(out, "RGB")


def composite(rgba: np.ndarray, background: tuple[int, int, int], out: np.ndarray | None = None) -> np.ndarray:
    """(H, W, 3) uint8: an RGBA uint8 image over a colour, each channel ``round(c a + b (1 - a))``
    with ``a = alpha / 255``, exactly: ``(c alpha + b (255 - alpha) + 127) // 255`` in integers (255
    is odd, so no sum is halfway between two; the blend Pillow's paste through the alpha channel
    rounds alike), in one compiled pass over the pixels as they lie.  ``out``: an (H, W, 3) uint8
    array (e.g. a canvas's inside) written in place and returned."""
    out = np.empty(rgba.shape[:2] + (3,), np.uint8) if out is None else out
    if out.shape != rgba.shape[:2] + (3,) or out.dtype != np.uint8:
        raise ValueError(f"out must be {rgba.shape[:2] + (3,)} uint8, got {out.dtype} {out.shape}")
    _composite(rgba, np.asarray(background, np.int64), out)
    return out


@compiled
def _composite(rgba: np.ndarray, background: np.ndarray, out: np.ndarray) -> None:
    """:func:`composite` into ``out``."""
    for y in range(rgba.shape[0]):
        for x in range(rgba.shape[1]):
            a = np.int64(rgba[y, x, 3])
            for c in range(3):
                out[y, x, c] = (np.int64(rgba[y, x, c]) * a + background[c] * (255 - a) + 127) // 255


def load_and_prepare(data: bytes | str | Path, spec: ImageSpec, max_pixels: int = MAX_PIXELS_DEFAULT) -> np.ndarray:
    """:func:`decode_image` then :func:`prepare_image`: encoded image to encoder input."""
    return prepare_image(decode_image(data, max_pixels), spec)


# -- the object's mask: alpha, the foreground network, or neither ------------------------------------


REMOVE_BACKGROUND = ("auto", "true", "false")
"""``auto``: an image with transparency uses its alpha, an opaque one the foreground network's mask;
``true``: the same, but an opaque image without a network is an error; ``false``: no mask (an
opaque image is cropped by its border colour, as before the network existed)."""


MIN_OBJECT_SIDE = 8
"""The fewest pixels across (the longer side of its box) an object cut out by its alpha may have: a
smaller one, enlarged to the encoder's input, is a blur that any shape matches."""


@dataclass
class Framed:
    """The encoder's input and what was done to get it: ``image`` (3, S, S); ``mask_source``
    "alpha" (the image's transparency), "network" (the foreground network) or "none"; ``box``
    (top, left, bottom, right), exclusive, the object's crop box in the image's pixels, None when
    the whole image was used; ``mask`` (H, W) uint8, the mask applied (None for "none"); ``shape``
    (H, W) of the image framed.  ``size``: the (height, width) of the image as uploaded when the
    image framed was a reduction of it (:func:`decode_photo`; None: the image framed is the
    upload); :func:`upload_box` and :func:`upload_mask` give them in the upload's pixels.
    ``confidence``: the network mask's certainty at its edge (:func:`model.image.mask.mask_confidence`;
    None for other sources)."""

    image: np.ndarray
    mask_source: str
    box: tuple[int, int, int, int] | None
    mask: np.ndarray | None
    shape: tuple[int, int]
    size: tuple[int, int] | None = None
    confidence: float | None = None


def upload_box(framed: Framed) -> tuple[int, int, int, int] | None:
    """The crop box of ``framed`` in the pixels of the image as uploaded (``framed.size``), grown
    outward to whole pixels; ``framed.box`` when the image framed was the upload."""
    if framed.box is None or framed.size is None or tuple(framed.size) == tuple(framed.shape):
        return framed.box
    (h, w), (H, W) = framed.shape, framed.size
    top, left, bottom, right = framed.box
    return (int(np.floor(top * H / h)), int(np.floor(left * W / w)),
            min(H, int(np.ceil(bottom * H / h))), min(W, int(np.ceil(right * W / w))))


def upload_mask(framed: Framed) -> np.ndarray | None:
    """The mask of ``framed`` at the size of the image as uploaded (``framed.size``), resized
    bilinearly; ``framed.mask`` when the image framed was the upload."""
    if framed.mask is None or framed.size is None or tuple(framed.size) == tuple(framed.shape):
        return framed.mask
    h, w = framed.size
    return np.asarray(Image.fromarray(np.ascontiguousarray(framed.mask, np.uint8), "L")
                      .resize((w, h), Image.Resampling.BILINEAR))


def frame_object(rgba: np.ndarray, spec: ImageSpec, segment=None, remove_background: str = "auto",
                 foreground_ratio: float | None = None, mask_spec: MaskSpec = MaskSpec(), refine=None,
                 region: tuple[int, int, int, int] | None = None) -> Framed:
    """Find the object, cut it out, frame it and make the encoder's input: the one path of photos
    into the image model (training, evaluation, the CLI and the service).

    The mask: an image with transparency (some alpha below 250) uses its alpha; otherwise, unless
    ``remove_background`` is "false", ``segment`` (a callable from an (H, W, 3|4) uint8 image, the
    photo as it lies or a view of it, to an object probability on a grid over the image, the
    foreground network) gives it (:func:`object_mask`:
    brought to the image through the guided filter, specks removed, a small object in a large
    photo segmented again at full resolution, then ``refine``'s second look at the object's
    square when given; NoObjectError when nothing is found).  The masked object is composited on
    ``spec.background`` and framed by :func:`prepare_image` (its crop box, a square the object
    fills ``foreground_ratio`` of, resized).  Without a mask, :func:`prepare_image` alone (an
    opaque image is cropped by its border colour).  ``region`` (top, left, bottom, right; a box
    the user drew): the object is looked for inside it only, and without a mask the region itself
    is the crop."""
    if remove_background not in REMOVE_BACKGROUND:
        raise ImageError(f"remove_background must be one of {', '.join(REMOVE_BACKGROUND)}, got {remove_background!r}")
    rgba = as_rgba(rgba)
    if int(rgba[..., 3].min()) < 250:
        return _frame_alpha(rgba, spec, foreground_ratio, region)
    if remove_background == "false" or segment is None:
        if remove_background == "true":
            raise ImageError("remove_background=true needs a foreground network, and this model has none; "
                             "send an image with transparency around the object")
        box = region or object_box(rgba, spec.border_tolerance)
        return Framed(prepare_image(rgba, spec, foreground_ratio=foreground_ratio, box=box), "none", box, None,
                      rgba.shape[:2])
    mask = _network_mask(rgba, segment, mask_spec, refine, region)         # the colour read as it lies in RGBA
    alpha = np.clip(np.round(mask * 255), 0, 255).astype(np.uint8)
    box = mask_bounds(alpha >= 128)
    cut = rgba.copy()
    cut[..., 3] = alpha
    image = prepare_image(cut, spec, foreground_ratio=foreground_ratio, box=box)
    return Framed(image, "network", box, alpha, rgba.shape[:2], confidence=mask_confidence(mask))


def _frame_alpha(rgba: np.ndarray, spec: ImageSpec, foreground_ratio: float | None,
                 region: tuple[int, int, int, int] | None) -> Framed:
    """The framing of an image with transparency: its alpha is the mask (inside ``region`` only)."""
    if region is not None:
        rgba = rgba.copy()
        inside = np.zeros(rgba.shape[:2], bool)
        inside[region[0]:region[2], region[1]:region[3]] = True
        rgba[~inside, 3] = 0
    peak = int(rgba[..., 3].max())
    if peak == 0:
        raise NoObjectError("the image is fully transparent" + (" inside the box" if region else "")
                            + ": there is no object to reconstruct")
    box = object_box(rgba, spec.border_tolerance)
    if box is None:
        raise NoObjectError(f"no object found in the image: no pixel is even half opaque (its alpha peaks at "
                            f"{peak} of 255); send the object opaque on a transparent background")
    if max(box[2] - box[0], box[3] - box[1]) < MIN_OBJECT_SIDE:
        raise NoObjectError(f"the object is only {box[3] - box[1]}x{box[2] - box[0]} pixels; send an image "
                            f"where it is at least {MIN_OBJECT_SIDE} pixels across")
    return Framed(prepare_image(rgba, spec, foreground_ratio=foreground_ratio, box=box), "alpha", box,
                  rgba[..., 3].copy(), rgba.shape[:2])


BOX_CONTEXT = 0.5
"""A box prompt is segmented with this share of its longest side around it (clipped to the
image), then the mask is kept inside the box only: the foreground network was trained on objects
with background about them, and a box drawn tightly around the object, segmented alone, loses
it (validation photos with a box 5% larger than the object: mask IoU 0.873 segmenting the box
alone, 0.905 without a box, 0.926 with this context; with a box drawn exactly at the object,
0.815 alone and 0.930 with it; chosen among 0.25, 0.5, 0.75 and 1 with boxes 0–20% larger than
the object, docs/journal/2026-11-29.md)."""


def _network_mask(rgb: np.ndarray, segment, spec: MaskSpec, refine, region: tuple[int, int, int, int] | None
                  ) -> np.ndarray:
    """The network's mask of ``rgb`` (:func:`object_mask`), or inside ``region`` only (segmented
    with :data:`BOX_CONTEXT` around it, specks and the least size then judged inside the box),
    placed in an image-sized mask (NoObjectError saying that the box holds no object, or an
    object under :data:`MIN_OBJECT_SIDE` pixels across)."""
    if region is None:
        return object_mask(rgb, segment, spec, refine)
    top, left, bottom, right = region
    y0, x0, y1, x1 = grown_box(region, *rgb.shape[:2], BOX_CONTEXT)
    lenient = replace(spec, keep=0.0, min_area=0.0)       # specks and sizes are judged in the box, not its context
    try:
        seen = object_mask(rgb[y0:y1, x0:x1], segment, lenient, refine)
        part = clean_mask(seen[top - y0:bottom - y0, left - x0:right - x0], spec)
    except NoObjectError as exc:
        raise NoObjectError(f"the box holds no object ({exc}); draw the box around the object") from None
    found = mask_bounds(part > 0.5)
    if max(found[2] - found[0], found[3] - found[1]) < MIN_OBJECT_SIDE:
        raise NoObjectError(f"the object in the box is only {found[3] - found[1]}x{found[2] - found[0]} pixels; "
                            f"draw the box around an object at least {MIN_OBJECT_SIDE} pixels across")
    mask = np.zeros(rgb.shape[:2], np.float32)
    mask[top:bottom, left:right] = part
    return mask


def compile_framing(spec: ImageSpec, mask_spec: MaskSpec) -> None:
    """Compile the network framing's kernels for the arrays a served photo brings, so that no
    request pays for it (numba compiles one version per array layout: a photo as decoded is
    contiguous, a crop of it is contiguous only when it spans whole rows): frames opaque RGBA
    photos, wide and tall, with a stand-in network that reads its input (:func:`mask_input`) and
    answers a small centred object on every look, with and without a box; then each kernel's
    wrapper on contiguous and strided arrays of either order of passes."""
    blob = np.zeros((mask_spec.size, mask_spec.size), np.float32)
    q = mask_spec.size // 4
    blob[q + q // 2:3 * q - q // 2, q + q // 2:3 * q - q // 2] = 1.0

    def stand_in(image: np.ndarray) -> np.ndarray:
        mask_input(image, mask_spec)
        return blob

    size = mask_spec.size
    for h, w in ((3 * size, 4 * size), (5 * size, 2 * size)):
        photo = np.full((h, w, 4), 255, np.uint8)
        for region in (None, (h // 8, w // 8, h - h // 8, w - w // 8)):
            try:
                frame_object(photo, spec, stand_in, "auto", None, mask_spec, None, region)
            except NoObjectError:
                pass
    photo = np.full((6 * size, 4 * size, 4), 255, np.uint8)
    for image in (photo[:, :2 * size], photo[:2 * size], photo[:3 * size, :size], photo[:3 * size, :, :3],
                  photo[:, :size], photo[:size], photo[:size, :size]):
        mask_input(image, mask_spec)                       # down or across first, a pass skipped, C or strided
    for part in (photo[:4, :4], photo[:4]):
        canvas = np.empty((part.shape[0] + 2, part.shape[1] + 2, 3), np.uint8)
        for out in (None, canvas[1:-1, 1:-1], canvas[1:-1]):
            composite(part, spec.background, out if out is None else out[:, :part.shape[1]])
    edge = np.zeros((64, 64), np.float32)
    for rows, cols in ((slice(20, 40), slice(20, 40)), (slice(20, 40), slice(0, 64))):
        edge[:] = 0.0
        edge[rows, cols] = 1.0
        mask_confidence(edge)                              # a band strided, or whole rows


def region_of(box: tuple[int, int, int, int], size: tuple[int, int], shape: tuple[int, int]
              ) -> tuple[int, int, int, int]:
    """A box the user drew, (left, top, right, bottom) in the pixels of the image as uploaded
    (``size``: its height and width), as (top, left, bottom, right) in the pixels of the image
    worked on (``shape``: a reduction of it, or itself), clipped to the image, grown outward to
    whole pixels; ImageError when it is empty or lies outside the image."""
    x0, y0, x1, y1 = box
    (H, W), (h, w) = size, shape
    if not (x0 < x1 and y0 < y1):
        raise ImageError(f"box must be left,top,right,bottom with left < right and top < bottom, got {x0},{y0},{x1},{y1}")
    if x1 <= 0 or y1 <= 0 or x0 >= W or y0 >= H:
        raise ImageError(f"box {x0},{y0},{x1},{y1} lies outside the {W}x{H} image")
    top, left = int(np.floor(max(y0, 0) * h / H)), int(np.floor(max(x0, 0) * w / W))
    bottom, right = int(np.ceil(min(y1, H) * h / H)), int(np.ceil(min(x1, W) * w / W))
    return top, left, max(bottom, top + 1), max(right, left + 1)
