"""Image preprocessing for shape-from-a-single-image, one function for training and serving.

Decodes anything Pillow reads, and HEIC through pillow-heif (EXIF rotation applied, first frame of
animations, palette, 16-bit, CMYK, greyscale), composites or keeps the background, crops to the object, pads to a square,
resizes and normalises.  NumPy + Pillow only (no torch): training, evaluation, export and the service all
call :func:`prepare_image` with the model's :class:`ImageSpec`, so they see identical tensors.
"""

from __future__ import annotations

import io
import struct
import warnings
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageOps, UnidentifiedImageError
from pillow_heif import register_heif_opener

register_heif_opener()          # HEIC/HEIF, the photos of phones that do not save JPEG, read like any other

MAX_PIXELS_DEFAULT = 40_000_000
"""Images with more pixels than this are refused before decoding (decompression bombs)."""
WORK_SIDE_DEFAULT = 1024
"""A photo's shorter side, in pixels, beyond which the service reduces it as it decodes it
(:func:`decode_photo`).  Every network input is far smaller (the foreground network's 128², the
encoder's crop), and an object filling a tenth of the short side is still a 100-pixel square for
the foreground network's second look; a 12-megapixel phone photo is worked on at 1024 x 1365."""


class ImageError(ValueError):
    """The input is not an image this preprocessing can use; the message says why and what to do."""


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
        return _spec_from_dict(cls, d)


def decode_image(data: bytes | str | Path, max_pixels: int = MAX_PIXELS_DEFAULT) -> np.ndarray:
    """RGBA uint8 (H, W, 4) of an encoded image (bytes or a path) at its full size; ImageError if it
    is not one (:func:`decode_photo` without a working size)."""
    return decode_photo(data, max_pixels, None).rgba


@dataclass(frozen=True)
class Decoded:
    """An image as decoded to be worked on: ``rgba`` (h, w, 4) uint8, ``size`` the (height, width)
    of the image as uploaded (EXIF orientation applied).  Invariant: ``rgba`` is ``size`` or a
    reduction of it with the same aspect ratio (within a pixel)."""

    rgba: np.ndarray
    size: tuple[int, int]


def decode_photo(data: bytes | str | Path, max_pixels: int = MAX_PIXELS_DEFAULT,
                 work_side: int | None = WORK_SIDE_DEFAULT) -> Decoded:
    """An encoded image (bytes or a path) decoded to RGBA uint8 with its shorter side reduced to
    ``work_side`` pixels when it is longer (None: full size); ImageError if it is not an image.

    The pixel count is checked from the header before the pixels are decoded.  A JPEG is decoded
    at the smallest of its scales 1/2, 1/4, 1/8 that is still at least the working size (the
    decoder's own scaling: a fraction of the work of a full decode); then every format is reduced
    with a box filter on premultiplied alpha, so transparent pixels' colours do not bleed.  EXIF
    orientation is applied; animations give their first frame; 16-bit and float images are scaled
    to 8 bits.
    """
    try:
        fh = io.BytesIO(data) if isinstance(data, (bytes, bytearray, memoryview)) else open(data, "rb")
    except OSError as exc:
        raise ImageError(f"cannot read the image: {exc.strerror}") from None
    with fh, warnings.catch_warnings():
        warnings.simplefilter("error", Image.DecompressionBombWarning)
        try:
            img = Image.open(fh)
            w, h = img.size
            if w < 1 or h < 1:
                raise ImageError("the image has no pixels")
            if w * h > max_pixels:
                raise ImageError(f"the image has {w}x{h} = {w * h:,} pixels, more than the limit of "
                                 f"{max_pixels:,}; send a smaller image")
            img.seek(0)
            size = (w, h) if img.getexif().get(_EXIF_ORIENTATION, 1) in (5, 6, 7, 8) else (h, w)
            if work_side is not None and min(w, h) > work_side and img.format == "JPEG":
                f = work_side / min(w, h)
                img.draft(img.mode, (int(np.ceil(w * f)), int(np.ceil(h * f))))
            img.load()
            img = ImageOps.exif_transpose(img)
            if work_side is not None and min(img.size) > work_side and img.mode in ("RGB", "L"):
                img = img.resize(_work_size(img.size, work_side), Image.Resampling.BOX)   # cheaper before RGBA
            rgba = _to_rgba(img)
            if work_side is not None and min(rgba.shape[:2]) > work_side:                 # the other modes
                rgba = _reduce(rgba, work_side)
            return Decoded(rgba, size)
        except ImageError:
            raise
        except (UnidentifiedImageError, Image.DecompressionBombError, Image.DecompressionBombWarning):
            raise ImageError("the data is not an image Pillow can read (PNG, JPEG, HEIC, WebP, AVIF, GIF, BMP, TIFF, "
                             "...)") from None
        except (OSError, SyntaxError, ValueError, EOFError, IndexError, KeyError, struct.error) as exc:
            raise ImageError(f"the image is truncated or corrupt ({type(exc).__name__}); send the whole file") from None


_EXIF_ORIENTATION = 0x0112
"""The EXIF tag of the orientation; values 5-8 turn the image a quarter (its sides swap)."""


def _work_size(size: tuple[int, int], short_side: int) -> tuple[int, int]:
    """(width, height) of an image of ``size`` (width, height) scaled to ``short_side`` on its
    shorter side."""
    f = short_side / min(size)
    return max(1, round(size[0] * f)), max(1, round(size[1] * f))


def _reduce(rgba: np.ndarray, short_side: int) -> np.ndarray:
    """``rgba`` resized with a box filter so that its shorter side is ``short_side`` (alpha
    premultiplied while resizing when the image has transparency)."""
    size = _work_size((rgba.shape[1], rgba.shape[0]), short_side)
    img = Image.fromarray(np.ascontiguousarray(rgba), "RGBA")
    if rgba[..., 3].min() == 255:
        return np.asarray(img.resize(size, Image.Resampling.BOX))
    return np.asarray(img.convert("RGBa").resize(size, Image.Resampling.BOX).convert("RGBA"))


def _to_rgba(img: Image.Image) -> np.ndarray:
    """RGBA uint8 of any Pillow mode (16-bit and float scaled by their range)."""
    if img.mode in ("I", "F") or img.mode.startswith("I;16"):
        a = np.nan_to_num(np.asarray(img, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        peak = float(a.max(initial=0.0))
        if img.mode == "F":
            top = 1.0 if peak <= 1.0 else peak
        elif img.mode.startswith("I;16") or 255 < peak <= 65535:
            top = 65535.0
        else:                            # 8-bit values in 32-bit pixels, or more than 16 bits used
            top = 255.0 if peak <= 255 else peak
        g = np.clip(a / top * 255.0, 0, 255).round().astype(np.uint8)
        return np.dstack([g, g, g, np.full_like(g, 255)])
    if img.mode == "P" and "transparency" in img.info:
        img = img.convert("RGBA")
    if img.mode in ("LA", "PA", "RGBa", "La"):
        img = img.convert("RGBA")
    return np.asarray(img.convert("RGBA"), dtype=np.uint8).copy()


def object_box(rgba: np.ndarray, tolerance: int = 24) -> tuple[int, int, int, int] | None:
    """(top, left, bottom, right), exclusive, of the object: opaque pixels where the image has
    transparency, else pixels that differ from the border's median colour; None when no pixel
    qualifies (fully transparent, or a flat image)."""
    alpha = rgba[..., 3]
    if alpha.min() < 250:
        mask = alpha >= 128
    else:
        rgb = rgba[..., :3]
        border = np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]])
        ref = np.median(border, axis=0).astype(np.float32)       # exact: integers or halves
        mask = np.zeros(rgb.shape[:2], bool)
        for c in range(3):                                       # per channel: max over a 3-axis is slow
            mask |= np.abs(rgb[..., c] - ref[c]) > tolerance
    return mask_bounds(mask)


def mask_bounds(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(top, left, bottom, right), exclusive, of the True pixels of a boolean mask; None if none."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        return None
    return int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1


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
    if keep_background or part[..., 3].min() == 255:
        rgb = part[..., :3]                             # compositing would change nothing
    else:
        rgb = composite(part, spec.background)
    pads = ((ys - y0, y0 + full - ye), (xs - x0, x0 + full - xe), (0, 0))
    if opaque:
        # an opaque photo: the real surroundings, the image's edges extended beyond its border
        canvas = np.pad(rgb, pads, mode="edge")
    else:
        canvas = np.empty((full, full, 3), np.uint8)
        canvas[:] = np.asarray(spec.background, np.uint8)
        canvas[pads[0][0]:full - pads[0][1], pads[1][0]:full - pads[1][1]] = rgb
    img = Image.fromarray(np.ascontiguousarray(canvas), "RGB")
    img = img.resize((spec.size, spec.size), Image.Resampling.BOX if full >= spec.size else Image.Resampling.BILINEAR)
    x = np.asarray(img, np.float32) / 255.0
    x = (x - np.asarray(spec.mean, np.float32)) / np.asarray(spec.std, np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1))


def composite(rgba: np.ndarray, background: tuple[int, int, int]) -> np.ndarray:
    """(H, W, 3) uint8: an RGBA uint8 image over a colour, each channel ``round(c a + b (1 - a))``
    with ``a = alpha / 255``, exactly (no sum of integers over 255 is halfway between two).  Pillow's
    paste through the alpha channel rounds that blend exactly (checked for every colour, alpha and
    background), at a fifth of the time of the same integer arithmetic in NumPy."""
    img = Image.fromarray(np.ascontiguousarray(rgba), "RGBA")
    out = Image.new("RGB", img.size, tuple(int(c) for c in background))
    out.paste(img.convert("RGB"), (0, 0), img.getchannel("A"))
    return np.asarray(out)


def rgb_of(rgba: np.ndarray) -> np.ndarray:
    """The (H, W, 3) uint8 colour channels of an RGBA image, as a contiguous array (what the
    foreground network's resizing reads; Pillow drops the alpha faster than a strided copy)."""
    return np.asarray(Image.fromarray(np.ascontiguousarray(rgba), "RGBA").convert("RGB"))


def load_and_prepare(data: bytes | str | Path, spec: ImageSpec, max_pixels: int = MAX_PIXELS_DEFAULT) -> np.ndarray:
    """:func:`decode_image` then :func:`prepare_image`: encoded image to encoder input."""
    return prepare_image(decode_image(data, max_pixels), spec)


# -- the object's mask: alpha, the foreground network, or neither ------------------------------------

REMOVE_BACKGROUND = ("auto", "true", "false")
"""``auto``: an image with transparency uses its alpha, an opaque one the foreground network's mask;
``true``: the same, but an opaque image without a network is an error; ``false``: no mask (an
opaque image is cropped by its border colour, as before the network existed)."""


class NoObjectError(ImageError):
    """The image shows no object to reconstruct (the mask is empty or too small)."""


MIN_OBJECT_SIDE = 8
"""The fewest pixels across (the longer side of its box) an object cut out by its alpha may have: a
smaller one, enlarged to the encoder's input, is a blur that any shape matches."""


@dataclass(frozen=True)
class MaskSpec:
    """How the foreground network takes an image: the whole image resized to ``size`` x ``size``
    (stretched: the network is trained on photos of many aspect ratios), normalised as the
    encoder's images.  ``min_area``: the share of the image the object must cover to count as
    found; ``keep``: mask components smaller than this share of the largest are dropped;
    ``refine``: when the object's square (its box's longest side grown by ``refine_margin`` on each
    side) covers less than this share of the image and has at least ``refine_min`` pixels a side,
    the network runs a second time on that square, so that a small object in a large photo is seen at
    the network's full resolution (0: never); ``refine_min``: the smallest square side looked at
    again (None: ``size``).  A network trained without second looks' views keeps the default: a
    smaller square, enlarged to ``size``, is blurred as none of its training photos is, and its
    second mask was worse than the first (validation IoU 0.814 against 0.836 without those second
    looks, docs/RESULTS.md).  ``guide``: the radius, in the network's pixels, of the guided filter
    that brings each look's mask from the network's grid to the image's resolution
    (:func:`guided_filter`, with the regulariser ``guide_eps``; 0: none, the mask is resized;
    on the 128² grid the radius is rounded to whole pixels), which brings back the edges and thin
    parts that the network's 128² loses; chosen on the validation split by ``python -m
    model.calibrate --mask-guide``.  ``crop_size``: the refinement network's input side (0: none):
    after the first mask, the object's square (its box's longest side grown by ``crop_margin`` on
    each side) is segmented again at ``crop_size``² with the first mask as a fourth channel
    (:func:`crop_input`), so that a thin part several photo pixels wide is several network pixels
    wide, and the refined mask replaces the first."""

    size: int = 128
    mean: tuple[float, float, float] = (0.5, 0.5, 0.5)
    std: tuple[float, float, float] = (0.25, 0.25, 0.25)
    min_area: float = 0.002
    keep: float = 0.1
    refine: float = 0.5
    refine_margin: float = 0.2
    refine_min: int | None = None
    guide: float = 0.0
    guide_eps: float = 1e-4
    crop_size: int = 0
    crop_margin: float = 0.1

    @property
    def refine_side(self) -> int:
        """The smallest square side that gets a second look."""
        return self.size if self.refine_min is None else self.refine_min

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> MaskSpec:
        return _spec_from_dict(cls, d)


def _spec_from_dict(cls, d: dict):
    """A spec dataclass from its JSON form (lists back to tuples)."""
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def mask_input(rgb: np.ndarray, spec: MaskSpec, size: int | None = None) -> np.ndarray:
    """The foreground network's input (3, size, size) float32 of an (H, W, 3) uint8 image
    (``size``: default ``spec.size``), stretched to the square: box-filtered down, bilinear up."""
    size = spec.size if size is None else size
    img = Image.fromarray(np.ascontiguousarray(rgb[..., :3]), "RGB")
    small = min(img.width, img.height) >= size
    img = img.resize((size, size), Image.Resampling.BOX if small else Image.Resampling.BILINEAR)
    x = np.asarray(img, np.float32) / 255.0
    x = (x - np.asarray(spec.mean, np.float32)) / np.asarray(spec.std, np.float32)
    return np.ascontiguousarray(x.transpose(2, 0, 1))


def crop_input(rgb: np.ndarray, first: np.ndarray, square: tuple[int, int, int, int], spec: MaskSpec) -> np.ndarray:
    """The refinement network's input (4, crop_size, crop_size) float32: the ``square`` (y0, y1,
    x0, x1, exclusive) of ``rgb`` (H, W, 3) uint8 as :func:`mask_input` makes it, and the first
    mask ``first`` (H, W) in [0, 1] over the same square, resized alike, as 2 p - 1."""
    y0, y1, x0, x1 = square
    size = spec.crop_size
    prior = resize_mask(np.asarray(first[y0:y1, x0:x1], np.float32), size, size)
    return np.concatenate([mask_input(rgb[y0:y1, x0:x1], spec, size), (2 * np.clip(prior, 0, 1) - 1)[None]])


def resize_mask(mask: np.ndarray, height: int, width: int) -> np.ndarray:
    """A float mask resized to (height, width): bilinear up, box-filtered down."""
    img = Image.fromarray(np.ascontiguousarray(mask, dtype=np.float32), "F")
    down = height <= img.height and width <= img.width
    return np.asarray(img.resize((width, height), Image.Resampling.BOX if down else Image.Resampling.BILINEAR),
                      np.float32)


def mask_output(logits: np.ndarray) -> np.ndarray:
    """(size, size) float32 object probability of the network's (size, size) logits: on the
    network's grid over the whole image (:func:`to_image` brings it to the image)."""
    x = np.asarray(logits, np.float32).reshape(logits.shape[-2:])
    return 1.0 / (1.0 + np.exp(-np.clip(x, -30, 30)))


def clean_mask(mask: np.ndarray, spec: MaskSpec, area: int | None = None) -> np.ndarray:
    """The mask without its specks: when components (of pixels above 0.5) smaller than ``spec.keep``
    of the largest exist, everything further than 2 pixels from the components kept is cleared;
    NoObjectError when what is left covers less than ``spec.min_area`` of the image (``area``
    pixels: by default the mask's own)."""
    from scipy import ndimage

    area = mask.size if area is None else area
    hard = mask > 0.5
    support = mask_bounds(hard)
    if support is None:
        raise NoObjectError("no object found in the image: no region of it looks like an object against its "
                            "background")
    top, left, bottom, right = support
    labels, n = ndimage.label(hard[top:bottom, left:right])     # every component lies in the box
    sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
    keep = np.flatnonzero(sizes >= spec.keep * sizes.max()) + 1
    if int(sizes[keep - 1].sum()) < spec.min_area * area:
        raise NoObjectError(f"no object found in the image: the largest region that looks like one covers "
                            f"{sizes.max() / area:.2%} of it (at least {spec.min_area:.1%} is needed); "
                            "send a photo where the object fills more of the frame")
    if len(keep) == n:
        return mask
    # the kept components grown by the 2-pixel reach, on the box grown by as much: nothing else survives
    kept_label = np.zeros(n + 1, bool)
    kept_label[keep] = True
    near = ndimage.binary_dilation(np.pad(kept_label[labels], 2), iterations=2)   # rows from top - 2
    y0, y1 = max(0, top - 2), min(mask.shape[0], bottom + 2)
    x0, x1 = max(0, left - 2), min(mask.shape[1], right + 2)
    out = np.zeros(mask.shape, np.float32)
    out[y0:y1, x0:x1] = np.where(near[y0 - top + 2:y1 - top + 2, x0 - left + 2:x1 - left + 2],
                                 mask[y0:y1, x0:x1], 0.0)
    return out


def guided_filter(rgb: np.ndarray, p: np.ndarray, radius: float, eps: float) -> np.ndarray:
    """``p`` (h, w) in [0, 1], an object probability on a grid over the whole of ``rgb`` (H, W, 3)
    uint8 (the foreground network's, or the image's own pixels), brought to the image's resolution
    with its grey image (luma) as the guide: He, Sun and Tang's guided filter (ECCV 2010), in the
    fast form of He and Sun (2015) where the grid is coarser than the image.  On the grid, in every
    (2 r + 1)² window (``r``: ``radius`` in grid pixels, rounded, at least 1), ``p`` is fitted as a
    linear function ``a I + b`` of the guide reduced to the grid, by least squares with the
    regulariser ``eps`` on ``a``;
    the fits of the windows over a grid point are averaged, and ``a``, ``b`` resized to the image
    (bilinear) give ``a I + b`` at every pixel of the image.  Where the image has an edge the mask
    follows it (the edges and thin parts a low-resolution mask blurs); where the image is flat the
    mask is smoothed.  The cost is the grid's, plus a few operations per image pixel.  Float32
    (H, W), clipped to [0, 1]."""
    from scipy import ndimage

    p = np.asarray(p, np.float32)
    grey = Image.fromarray(np.ascontiguousarray(rgb[..., :3]), "RGB").convert("L")      # luma, ITU-R 601
    guide = np.asarray(grey, np.float32) / np.float32(255)
    (h, w), (H, W) = p.shape, guide.shape
    g = guide if (h, w) == (H, W) else resize_mask(guide, h, w)
    size = 2 * max(1, round(radius)) + 1

    def box(x: np.ndarray) -> np.ndarray:
        return ndimage.uniform_filter(x, size, mode="reflect")

    mean_i, mean_p = box(g), box(p)
    a = (box(g * p) - mean_i * mean_p) / (box(g * g) - mean_i * mean_i + np.float32(eps))
    a_mean, b_mean = box(a), box(mean_p - a * mean_i)
    if (h, w) != (H, W):
        a_mean, b_mean = resize_mask(a_mean, H, W), resize_mask(b_mean, H, W)
    return np.clip(a_mean * guide + b_mean, 0.0, 1.0)


def to_image(rgb: np.ndarray, p: np.ndarray, spec: MaskSpec) -> np.ndarray:
    """An object probability ``p`` on a grid over the whole of ``rgb`` (the network's ``spec.size``
    square, or the image's own pixels) at the image's (H, W), float32 in [0, 1]: through
    ``spec``'s guided filter (its radius given in the network's pixels, scaled to the grid), else
    resized (bilinear)."""
    p = np.asarray(p, np.float32)
    if spec.guide > 0:
        return guided_filter(rgb, p, spec.guide * max(p.shape) / spec.size, spec.guide_eps)
    return np.clip(p if p.shape == rgb.shape[:2] else resize_mask(p, *rgb.shape[:2]), 0.0, 1.0)


def object_square(box: tuple[int, int, int, int], height: int, width: int, margin: float) -> tuple[int, int, int, int]:
    """(y0, y1, x0, x1), exclusive: the square about ``box`` (top, left, bottom, right) whose side
    is the box's longest side grown by ``margin`` on each side, clipped to a height x width image:
    where the second look (:func:`object_mask`) segments a small object again."""
    top, left, bottom, right = box
    side = int(round(max(bottom - top, right - left) * (1 + 2 * margin)))
    ty, tx = int(round((top + bottom - side) / 2)), int(round((left + right - side) / 2))
    return max(0, ty), min(height, ty + side), max(0, tx), min(width, tx + side)


def refine_square(box: tuple[int, int, int, int], height: int, width: int,
                  spec: MaskSpec) -> tuple[int, int, int, int] | None:
    """The square a second look would segment, (y0, y1, x0, x1) (:func:`object_square` with
    ``spec.refine_margin``), or None when it covers ``spec.refine`` of the image or more (a large
    object: the first look saw it well enough)."""
    y0, y1, x0, x1 = object_square(box, height, width, spec.refine_margin)
    return None if (y1 - y0) * (x1 - x0) >= spec.refine * height * width else (y0, y1, x0, x1)


def object_mask(rgb: np.ndarray, segment, spec: MaskSpec, refine=None) -> np.ndarray:
    """(H, W) float32 object mask of an opaque image from ``segment`` (the foreground network: an
    (h, w, 3) uint8 image to its object probability on a grid over the whole image, the network's
    ``spec.size`` square or the image's own pixels), brought to the image (:func:`to_image`: the
    guided filter of ``spec``), specks removed (:func:`clean_mask`; NoObjectError when nothing is
    left); a small object in a large photo is segmented again in its square (see
    :class:`MaskSpec`), the second mask replacing the first there and clearing it elsewhere
    (unless it finds nothing: then the first stands).  ``refine`` (the refinement network: a
    (4, crop_size, crop_size) :func:`crop_input` to its object probability on that grid), when
    given and ``spec.crop_size`` is set, then segments the object's square once more
    (:func:`refined_mask`)."""
    h, w = rgb.shape[:2]

    def look(image: np.ndarray) -> np.ndarray:
        return to_image(image, segment(image), spec)

    mask = clean_mask(look(rgb), spec)
    square = refine_square(mask_bounds(mask > 0.5), h, w, spec)
    if square is not None and min(square[1] - square[0], square[3] - square[2]) >= spec.refine_side:
        y0, y1, x0, x1 = square
        try:
            part = clean_mask(look(np.ascontiguousarray(rgb[y0:y1, x0:x1])), spec, h * w)
            mask = np.zeros_like(mask)
            mask[y0:y1, x0:x1] = part
        except NoObjectError:            # the closer look lost the object: keep the first look's mask
            pass
    if refine is None or not spec.crop_size:
        return mask
    return refined_mask(rgb, mask, refine, spec)


def refined_mask(rgb: np.ndarray, first: np.ndarray, refine, spec: MaskSpec) -> np.ndarray:
    """The first mask ``first`` (H, W) of ``rgb`` refined: the object's square (:func:`object_square`
    with ``spec.crop_margin``) segmented by ``refine`` from :func:`crop_input`, its probability
    resized to the square (bilinear) and cleaned (:func:`clean_mask`), replacing the first mask
    there and clearing it elsewhere; the first mask when the refinement finds nothing."""
    h, w = rgb.shape[:2]
    y0, y1, x0, x1 = square = object_square(mask_bounds(first > 0.5), h, w, spec.crop_margin)
    p = np.asarray(refine(crop_input(rgb, first, square, spec)), np.float32)
    try:
        part = clean_mask(np.clip(resize_mask(p, y1 - y0, x1 - x0), 0, 1), spec, h * w)
    except NoObjectError:
        return first
    out = np.zeros_like(first)
    out[y0:y1, x0:x1] = part
    return out


def mask_iou(ours: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two boolean masks (0 when both are empty)."""
    return float((ours & truth).sum() / max(1, (ours | truth).sum()))


@dataclass
class Framed:
    """The encoder's input and what was done to get it: ``image`` (3, S, S); ``mask_source``
    "alpha" (the image's transparency), "network" (the foreground network) or "none"; ``box``
    (top, left, bottom, right), exclusive, the object's crop box in the image's pixels, None when
    the whole image was used; ``mask`` (H, W) uint8, the mask applied (None for "none"); ``shape``
    (H, W) of the image framed.  ``size``: the (height, width) of the image as uploaded when the
    image framed was a reduction of it (:func:`decode_photo`; None: the image framed is the
    upload); :func:`upload_box` and :func:`upload_mask` give them in the upload's pixels."""

    image: np.ndarray
    mask_source: str
    box: tuple[int, int, int, int] | None
    mask: np.ndarray | None
    shape: tuple[int, int]
    size: tuple[int, int] | None = None


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
                 foreground_ratio: float | None = None, mask_spec: MaskSpec = MaskSpec()) -> Framed:
    """Find the object, cut it out, frame it and make the encoder's input: the one path of photos
    into the image model (training, evaluation, the CLI and the service).

    The mask: an image with transparency (some alpha below 250) uses its alpha; otherwise, unless
    ``remove_background`` is "false", ``segment`` (a callable from (H, W, 3) uint8 to an object
    probability on a grid over the image, the foreground network) gives it (:func:`object_mask`:
    brought to the image through the guided filter, specks removed, a small object in a large
    photo segmented again at full resolution; NoObjectError when nothing is found).  The masked
    object is composited on ``spec.background`` and framed by :func:`prepare_image` (its crop box,
    a square the object fills ``foreground_ratio`` of, resized).  Without a mask,
    :func:`prepare_image` alone (an opaque image is cropped by its border colour)."""
    if remove_background not in REMOVE_BACKGROUND:
        raise ImageError(f"remove_background must be one of {', '.join(REMOVE_BACKGROUND)}, got {remove_background!r}")
    rgba = as_rgba(rgba)
    has_alpha = int(rgba[..., 3].min()) < 250
    if has_alpha:
        peak = int(rgba[..., 3].max())
        if peak == 0:
            raise NoObjectError("the image is fully transparent: there is no object to reconstruct")
        box = object_box(rgba, spec.border_tolerance)
        if box is None:
            raise NoObjectError(f"no object found in the image: no pixel is even half opaque (its alpha peaks at "
                                f"{peak} of 255); send the object opaque on a transparent background")
        if max(box[2] - box[0], box[3] - box[1]) < MIN_OBJECT_SIDE:
            raise NoObjectError(f"the object is only {box[3] - box[1]}x{box[2] - box[0]} pixels; send an image "
                                f"where it is at least {MIN_OBJECT_SIDE} pixels across")
        return Framed(prepare_image(rgba, spec, foreground_ratio=foreground_ratio, box=box), "alpha", box,
                      rgba[..., 3].copy(), rgba.shape[:2])
    if remove_background == "false" or segment is None:
        if remove_background == "true":
            raise ImageError("remove_background=true needs a foreground network, and this model has none; "
                             "send an image with transparency around the object")
        box = object_box(rgba, spec.border_tolerance)
        return Framed(prepare_image(rgba, spec, foreground_ratio=foreground_ratio, box=box), "none", box, None,
                      rgba.shape[:2])
    mask = object_mask(rgb_of(rgba), segment, mask_spec)
    alpha = np.clip(np.round(mask * 255), 0, 255).astype(np.uint8)
    box = mask_bounds(alpha >= 128)
    cut = rgba.copy()
    cut[..., 3] = alpha
    image = prepare_image(cut, spec, foreground_ratio=foreground_ratio, box=box)
    return Framed(image, "network", box, alpha, rgba.shape[:2])
