"""Image preprocessing for shape-from-a-single-image, one function for training and serving.

Decodes anything Pillow reads (EXIF rotation applied, first frame of animations, palette, 16-bit,
CMYK, greyscale), composites or keeps the background, crops to the object, pads to a square,
resizes and normalises.  NumPy + Pillow only: training, evaluation, export and the service all
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

MAX_PIXELS_DEFAULT = 40_000_000
"""Images with more pixels than this are refused before decoding (decompression bombs)."""


class ImageError(ValueError):
    """The input is not an image this preprocessing can use; the message says why and what to do."""


@dataclass(frozen=True)
class ImageSpec:
    """How an encoder expects its image: ``size`` x ``size`` RGB, channel-wise normalised.

    ``background``: the RGB colour transparent pixels are composited onto. ``margin``: the share of
    the square's side left empty around the object's crop box (on each side). ``border_tolerance``:
    how far (0-255, max over channels) a pixel may differ from the border colour and still count as
    background when an opaque image is cropped.
    """

    size: int = 128
    mean: tuple[float, float, float] = (0.5, 0.5, 0.5)
    std: tuple[float, float, float] = (0.25, 0.25, 0.25)
    background: tuple[int, int, int] = (255, 255, 255)
    margin: float = 0.05
    border_tolerance: int = 24

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> ImageSpec:
        return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def decode_image(data: bytes | str | Path, max_pixels: int = MAX_PIXELS_DEFAULT) -> np.ndarray:
    """RGBA uint8 (H, W, 4) of an encoded image (bytes or a path); ImageError if it is not one.

    The pixel count is checked from the header before the pixels are decoded.  EXIF orientation
    is applied; animations give their first frame; 16-bit and float images are scaled to 8 bits.
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
            img.load()
            img = ImageOps.exif_transpose(img)
            return _to_rgba(img)
        except ImageError:
            raise
        except (UnidentifiedImageError, Image.DecompressionBombError, Image.DecompressionBombWarning):
            raise ImageError("the data is not an image Pillow can read (PNG, JPEG, WebP, GIF, BMP, TIFF, ...)") from None
        except (OSError, SyntaxError, ValueError, EOFError, IndexError, KeyError, struct.error) as exc:
            raise ImageError(f"the image is truncated or corrupt ({type(exc).__name__}); send the whole file") from None


def _to_rgba(img: Image.Image) -> np.ndarray:
    """RGBA uint8 of any Pillow mode (16-bit and float scaled by their range)."""
    if img.mode in ("I", "F") or img.mode.startswith("I;16"):
        a = np.nan_to_num(np.asarray(img, dtype=np.float64), nan=0.0, posinf=0.0, neginf=0.0)
        peak = float(a.max(initial=0.0))
        if img.mode == "F":
            top = 1.0 if peak <= 1.0 else peak
        else:
            top = 65535.0 if img.mode.startswith("I;16") or peak > 255 else 255.0
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
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        return None
    return int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1


def prepare_image(rgba: np.ndarray, spec: ImageSpec, keep_background: bool = False) -> np.ndarray:
    """The encoder's input (3, size, size) float32 from an RGBA (or RGB) uint8 image.

    Transparent pixels are composited onto ``spec.background`` (``keep_background`` keeps the
    image's own colour under them instead).  The crop is the :func:`object_box`, or the whole image
    where it finds nothing (a fully transparent image is an ImageError: there is no object); the
    crop is grown to a square plus ``spec.margin`` per side (taking the image's own surroundings,
    beyond its border the background colour or, for an opaque image, its edge pixels), resized with
    a box filter (antialiasing) and normalised by ``spec.mean`` / ``spec.std``.
    """
    rgba = np.asarray(rgba)
    if rgba.ndim != 3 or rgba.shape[2] not in (3, 4) or rgba.dtype != np.uint8:
        raise ImageError(f"expected an (H, W, 3|4) uint8 image, got {rgba.dtype} {rgba.shape}")
    if rgba.shape[2] == 3:
        rgba = np.concatenate([rgba, np.full(rgba.shape[:2] + (1,), 255, np.uint8)], axis=2)
    if rgba[..., 3].max() == 0:
        raise ImageError("the image is fully transparent: there is no object to reconstruct")
    box = object_box(rgba, spec.border_tolerance)
    h, w = rgba.shape[:2]
    top, left, bottom, right = box if box is not None else (0, 0, h, w)
    side = max(bottom - top, right - left)
    full = side + 2 * int(round(side * spec.margin / max(1e-6, 1 - 2 * spec.margin)))
    y0 = top - (full - (bottom - top)) // 2            # the square around the crop, image coordinates
    x0 = left - (full - (right - left)) // 2
    ys, ye, xs, xe = max(0, y0), min(h, y0 + full), max(0, x0), min(w, x0 + full)
    part = rgba[ys:ye, xs:xe]                           # only the square's pixels are converted
    opaque = keep_background or rgba[..., 3].min() >= 250
    if keep_background or part[..., 3].min() == 255:
        rgb = part[..., :3]                             # compositing would change nothing
    else:
        a = part[..., 3:4].astype(np.float32) / 255.0
        rgb = part[..., :3].astype(np.float32) * a + np.asarray(spec.background, np.float32) * (1 - a)
        rgb = np.clip(rgb.round(), 0, 255).astype(np.uint8)
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


def load_and_prepare(data: bytes | str | Path, spec: ImageSpec, max_pixels: int = MAX_PIXELS_DEFAULT) -> np.ndarray:
    """:func:`decode_image` then :func:`prepare_image`: encoded image to encoder input."""
    return prepare_image(decode_image(data, max_pixels), spec)
