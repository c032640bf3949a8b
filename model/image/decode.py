"""Images decoded to be worked on: anything Pillow reads, and HEIC through pillow-heif (EXIF
rotation applied, first frame of animations, palette, 16-bit, CMYK, greyscale), to RGBA uint8,
large photos reduced as they are decoded.  NumPy + Pillow only (no torch)."""

from __future__ import annotations

import io
import struct
import warnings
from dataclasses import dataclass
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
