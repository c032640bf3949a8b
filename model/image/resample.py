"""Pillow's box-filter reduction of an 8-bit image, reproduced bit for bit and fused with the
networks' normalisation: the foreground network's input made in one compiled pass from the photo's
pixels as they lie (RGB or RGBA, a crop's strided view), without the copies and the float image of
``Image.fromarray(...).resize(..., BOX)`` then NumPy.

Pillow 13 resamples 8-bit images in two passes, each with its taps normalised to 22-bit fixed point
(``normalize_coeffs_8bpc`` of ``libImaging/Resample.c``), every sum started at a half and clipped
to 0..255 (``clip8``), the first pass's result stored in 8 bits.  A size that does not change has
no pass.  Which pass comes first was found by comparing both orders with Pillow's output (2,249
sizes to squares of 64, 96 and 128, near the switch and at random): down first when the height
exceeds twice the width less the output side (``h > 2 w - size``), across first otherwise.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from model.octree.jit import compiled

PRECISION_BITS = 22
"""Pillow's fixed-point precision of 8-bit resampling taps (32 - 8 - 2)."""


def _box(t: float) -> float:
    return 1.0 if -0.5 < t <= 0.5 else 0.0


def _triangle(t: float) -> float:
    t = abs(t)
    return 1.0 - t if t < 1.0 else 0.0


FILTERS = {"box": (0.5, _box), "bilinear": (1.0, _triangle)}
"""Pillow's resampling filters used here: (support, weight of a distance in input pixels)."""


@lru_cache(maxsize=128)
def pillow_taps(size: int, out: int, kind: str) -> tuple[np.ndarray, np.ndarray]:
    """Pillow's taps (its ``precompute_coeffs``) of the filter ``kind`` (:data:`FILTERS`) from
    ``size`` pixels to ``out``: per output pixel the first input pixel and the count (out, 2), and
    the weights normalised to sum 1 (out, k), in double, summed and divided as Pillow does; the
    support widened where the size is reduced (read-only)."""
    half, weight = FILTERS[kind]
    scale = size / out
    filterscale = max(scale, 1.0)
    support = half * filterscale
    bounds = np.zeros((out, 2), np.int64)
    weights = np.zeros((out, int(np.ceil(support)) * 2 + 1))
    for xx in range(out):
        centre = (xx + 0.5) * scale
        first = max(int(centre - support + 0.5), 0)
        count = min(int(centre + support + 0.5), size) - first
        total = 0.0
        for x in range(count):
            weights[xx, x] = weight((x + first - centre + 0.5) * (1.0 / filterscale))
            total += weights[xx, x]
        if total != 0.0:
            weights[xx, :count] /= total
        bounds[xx] = first, count
    bounds.setflags(write=False)
    weights.setflags(write=False)
    return bounds, weights


@lru_cache(maxsize=64)
def box_taps(size: int, out: int) -> tuple[np.ndarray, np.ndarray]:
    """Pillow's box-filter taps from ``size`` pixels to ``out`` (:func:`pillow_taps` then its
    ``normalize_coeffs_8bpc``): the bounds, and the fixed-point weights (out, k), int64 (read-only)."""
    bounds, weights = pillow_taps(size, out, "box")
    fixed = (0.5 + weights * (1 << PRECISION_BITS)).astype(np.int64)       # non-negative: truncation rounds
    fixed.setflags(write=False)
    return bounds, fixed


def box_input(image: np.ndarray, size: int, mean: np.ndarray, std: np.ndarray) -> np.ndarray:
    """(3, size, size) float32: the first three channels of ``image`` (H, W, C >= 3) uint8, with
    H, W >= ``size``, reduced to size x size as ``Image.fromarray(rgb).resize((size, size), BOX)``
    does, then ``(v / 255 - mean) / std`` in float32 as NumPy computes it (``mean``, ``std``:
    float32 (3,))."""
    h, w = image.shape[:2]
    if min(h, w) < size or image.ndim != 3 or image.shape[2] < 3 or image.dtype != np.uint8:
        raise ValueError(f"box_input reduces an (H, W, 3|4) uint8 image of sides >= {size}, got "
                         f"{image.dtype} {image.shape}")
    (across_bounds, across), (down_bounds, down) = box_taps(w, size), box_taps(h, size)
    need_across, need_down = w != size, h != size
    if need_down and h > 2 * w - size:                                    # down first
        band = _down(image, 0, down_bounds, down)
        band = _across(band, 0, size, across_bounds, across) if need_across else band
    else:                                                                 # across first, on the rows read
        first, last = (int(down_bounds[0, 0]), int(down_bounds[-1].sum())) if need_down else (0, h)
        band = _across(image, first, last, across_bounds, across) if need_across else image[first:last]
        band = _down(band, first, down_bounds, down) if need_down else band
    out = np.empty((3, size, size), np.float32)
    _normalised(band, np.asarray(mean, np.float32), np.asarray(std, np.float32), out)
    return out


@compiled
def _across(image, first, last, bounds, taps):
    """The pass across of rows ``first .. last`` of ``image`` (.., W, >= 3) to ``len(bounds)``
    columns, 8-bit (last - first, columns, 3)."""
    rows = np.empty((last - first, len(bounds), 3), np.uint8)
    half = np.int64(1) << (PRECISION_BITS - 1)
    for y in range(first, last):
        for xx in range(len(bounds)):
            x0, count = bounds[xx, 0], bounds[xx, 1]
            s0 = s1 = s2 = half
            for x in range(count):
                k = taps[xx, x]
                s0 += np.int64(image[y, x0 + x, 0]) * k
                s1 += np.int64(image[y, x0 + x, 1]) * k
                s2 += np.int64(image[y, x0 + x, 2]) * k
            rows[y - first, xx, 0] = _clip8(s0)
            rows[y - first, xx, 1] = _clip8(s1)
            rows[y - first, xx, 2] = _clip8(s2)
    return rows


@compiled
def _down(image, first, bounds, taps):
    """The pass down of ``image`` (rows from ``first`` of the whole image, W, >= 3) to
    ``len(bounds)`` rows, 8-bit (rows, W, 3), a row of sums at a time."""
    w = image.shape[1]
    out = np.empty((len(bounds), w, 3), np.uint8)
    sums = np.empty((w, 3), np.int64)
    for yy in range(len(bounds)):
        y0, count = bounds[yy, 0] - first, bounds[yy, 1]
        sums[:] = np.int64(1) << (PRECISION_BITS - 1)
        for y in range(count):
            k = taps[yy, y]
            for x in range(w):
                for c in range(3):
                    sums[x, c] += np.int64(image[y0 + y, x, c]) * k
        for x in range(w):
            for c in range(3):
                out[yy, x, c] = _clip8(sums[x, c])
    return out


@compiled
def _normalised(band, mean, std, out) -> None:
    """``(band / 255 - mean) / std`` in float32 of an 8-bit (size, size, >= 3) into ``out`` (3, size, size)."""
    scale = np.float32(255.0)
    for y in range(out.shape[1]):
        for x in range(out.shape[2]):
            for c in range(3):
                out[c, y, x] = (np.float32(band[y, x, c]) / scale - mean[c]) / std[c]


@compiled
def _clip8(s: int) -> np.uint8:
    """Pillow's ``clip8``: the fixed-point sum shifted down and clipped to 0..255."""
    v = s >> PRECISION_BITS
    return np.uint8(0 if v < 0 else (255 if v > 255 else v))
