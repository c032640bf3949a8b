"""The object's mask in an opaque photo: the foreground network's input and output, the guided
filter that brings its grid to the photo's pixels, the clean-up, the second look at a small
object, and the refinement network's look at the object's square.  One path for training,
evaluation, the CLI and the service.  NumPy, SciPy, Pillow and numba kernels (the network input's
reduction, :mod:`model.image.resample`; the guided filter's blend; the edge band) only (no
torch); the networks are passed in as callables."""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from PIL import Image
from scipy import ndimage

from model.octree.jit import compiled, inlined

from .decode import ImageError
from .resample import box_input, pillow_taps


class NoObjectError(ImageError):
    """The image shows no object to reconstruct (the mask is empty or too small)."""


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
    looks, docs/journal/2026-11-experiments.md).  ``guide``: the radius, in the network's pixels, of the guided filter
    that brings each look's mask from the network's grid to the image's resolution
    (:func:`guided_filter`, with the regulariser ``guide_eps``; 0: none, the mask is resized;
    on the 128² grid the radius is rounded to whole pixels), which brings back the edges and thin
    parts that the network's 128² loses; chosen on the validation split by ``python -m
    research.calibrate --mask-guide``.  ``crop_size``: the refinement network's input side (0: none):
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
        return spec_from_dict(cls, d)


def spec_from_dict(cls, d: dict):
    """A spec dataclass from its JSON form (lists back to tuples)."""
    return cls(**{k: tuple(v) if isinstance(v, list) else v for k, v in d.items()})


def mask_bounds(mask: np.ndarray) -> tuple[int, int, int, int] | None:
    """(top, left, bottom, right), exclusive, of the True pixels of a boolean mask; None if none."""
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    if len(rows) == 0:
        return None
    return int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1


def mask_input(rgb: np.ndarray, spec: MaskSpec, size: int | None = None) -> np.ndarray:
    """The foreground network's input (3, size, size) float32 of an (H, W, 3|4) uint8 image (its
    colour channels; ``size``: default ``spec.size``), stretched to the square as Pillow resizes:
    box-filtered down (:func:`model.image.resample.box_input`, in one pass from the pixels as they
    lie), bilinear up."""
    size = spec.size if size is None else size
    mean, std = np.asarray(spec.mean, np.float32), np.asarray(spec.std, np.float32)
    if min(rgb.shape[:2]) >= size:
        return box_input(rgb, size, mean, std)
    img = Image.fromarray(np.ascontiguousarray(rgb[..., :3]), "RGB")
    img = img.resize((size, size), Image.Resampling.BILINEAR)
    x = np.asarray(img, np.float32) / 255.0
    return np.ascontiguousarray(((x - mean) / std).transpose(2, 0, 1))


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
    down = _box_filtered(img.height, img.width, height, width)
    return np.asarray(img.resize((width, height), Image.Resampling.BOX if down else Image.Resampling.BILINEAR),
                      np.float32)


def _box_filtered(h: int, w: int, height: int, width: int) -> bool:
    """Whether :func:`resize_mask` takes an (h, w) mask to (height, width) with the box filter (both
    sides shrink or stay), not bilinearly."""
    return height <= h and width <= w


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
    near = cross_dilation(np.pad(kept_label[labels], 2), 2)                      # rows from top - 2
    y0, y1 = max(0, top - 2), min(mask.shape[0], bottom + 2)
    x0, x1 = max(0, left - 2), min(mask.shape[1], right + 2)
    out = np.zeros(mask.shape, np.float32)
    out[y0:y1, x0:x1] = np.where(near[y0 - top + 2:y1 - top + 2, x0 - left + 2:x1 - left + 2],
                                 mask[y0:y1, x0:x1], 0.0)
    return out


def cross_dilation(mask: np.ndarray, times: int) -> np.ndarray:
    """A 2-D boolean mask dilated ``times`` times by the 4-neighbour cross (``ndimage.binary_dilation``
    with its default structure, ``iterations=times``, nothing beyond the border), by shifted ORs."""
    out = mask.copy()
    for _ in range(times):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        grown[:, 1:] |= out[:, :-1]
        grown[:, :-1] |= out[:, 1:]
        out = grown
    return out


def guide_of(rgb: np.ndarray) -> np.ndarray:
    """The guided filter's guide of an (H, W, 3|4) uint8 image: its grey image (luma, ITU-R 601, as
    Pillow rounds it per pixel, so a crop's guide is the guide's crop) in [0, 1], float32 (H, W).
    Pillow's RGBA to L reads the colour as its RGB to L does (the same for all 2^24 colours,
    whatever the alpha), so an RGBA image is converted as it lies."""
    mode = "RGBA" if rgb.shape[2] == 4 else "RGB"
    grey = Image.fromarray(np.ascontiguousarray(rgb if mode == "RGBA" else rgb[..., :3]), mode).convert("L")
    return np.asarray(grey, np.float32) / np.float32(255)


def guided_filter(rgb: np.ndarray, p: np.ndarray, radius: float, eps: float,
                  guide: np.ndarray | None = None) -> np.ndarray:
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
    (H, W), clipped to [0, 1].  ``guide``: :func:`guide_of` ``rgb`` when the caller has it."""
    p = np.asarray(p, np.float32)
    guide = guide_of(rgb) if guide is None else guide
    (h, w), (H, W) = p.shape, guide.shape
    a_mean, b_mean = _guided_coefficients(p, guide, radius, eps)
    if (h, w) != (H, W) and not _box_filtered(h, w, H, W):  # resized bilinearly: in one pass, A and B never made
        return bilinear_blend(a_mean, b_mean, guide)
    if (h, w) != (H, W):
        a_mean, b_mean = resize_mask(a_mean, H, W), resize_mask(b_mean, H, W)
    return np.clip(a_mean * guide + b_mean, 0.0, 1.0)


def _guided_coefficients(p: np.ndarray, guide: np.ndarray, radius: float, eps: float) -> tuple[np.ndarray, np.ndarray]:
    """The guided filter's averaged coefficients ``a``, ``b`` on ``p``'s grid (:func:`guided_filter`)."""
    (h, w), (H, W) = p.shape, guide.shape
    g = guide if (h, w) == (H, W) else resize_mask(guide, h, w)
    size = 2 * max(1, round(radius)) + 1

    def box(x: np.ndarray) -> np.ndarray:
        return ndimage.uniform_filter(x, size, mode="reflect")

    mean_i, mean_p = box(g), box(p)
    a = (box(g * p) - mean_i * mean_p) / (box(g * g) - mean_i * mean_i + np.float32(eps))
    return box(a), box(mean_p - a * mean_i)


FIRST_LOOK_WINDOW = 0.5
"""The largest share of the photo the first look's window (:func:`first_look_window`) may cover;
a larger one is computed whole (its object is too large for a second look to be likely)."""


def blend_coefficients(p: np.ndarray, spec: MaskSpec, guide: np.ndarray | None
                       ) -> tuple[np.ndarray, np.ndarray] | None:
    """The guided filter's averaged coefficients ``a``, ``b`` of ``p`` where :func:`to_image`
    blends them bilinearly to the guide's size (``bilinear_blend(a, b, guide)`` is then its
    result, bit for bit); None where it does not (no guided filter, the grid at the image's size or
    reduced both ways)."""
    if spec.guide <= 0 or guide is None:
        return None
    p = np.asarray(p, np.float32)
    (h, w), (H, W) = p.shape, guide.shape
    if (h, w) == (H, W) or _box_filtered(h, w, H, W):
        return None
    return _guided_coefficients(p, guide, spec.guide * max(p.shape) / spec.size, spec.guide_eps)


def first_look_window(a: np.ndarray, b: np.ndarray, guide: np.ndarray
                      ) -> tuple[np.ndarray, tuple[int, int, int, int]] | None:
    """The first look's mask (``bilinear_blend(a, b, guide)``, :func:`blend_coefficients`) on a
    window (y0, y1, x0, x1) outside which none of its values exceeds 0.5, and the window; None where
    the coefficients are not finite, nothing can pass 0.5, or the window covers more than
    :data:`FIRST_LOOK_WINDOW` of the photo.  Each value is ``a I + b``, with ``a``, ``b``
    interpolated from the grid with weights that sum to 1 and ``I`` in [0, 1], so it is at most the
    largest ``max(b, a + b)`` of the grid points it is interpolated from; the window holds every
    pixel interpolated from a grid point where that bound, widened by far more than the float32
    rounding of the passes, exceeds 0.5.  The values in it are those of the whole mask, bit for
    bit."""
    (h, w), (H, W) = a.shape, guide.shape
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return None
    slack = 1e-5 * (1.0 + float(np.abs(a).max()) + float(np.abs(b).max()))
    may_pass = np.maximum(b, a + b) > 0.5 - slack
    rows, cols = np.flatnonzero(may_pass.any(axis=1)), np.flatnonzero(may_pass.any(axis=0))
    if len(rows) == 0:
        return None
    across, down = pillow_taps(w, W, "bilinear"), pillow_taps(h, H, "bilinear")
    y0, y1 = _reaching(down[0], rows[0], rows[-1])
    x0, x1 = _reaching(across[0], cols[0], cols[-1])
    if (y1 - y0) * (x1 - x0) > FIRST_LOOK_WINDOW * H * W:
        return None
    return bilinear_blend(a, b, guide, (y0, y1, x0, x1)), (y0, y1, x0, x1)


def _reaching(bounds: np.ndarray, first: int, last: int) -> tuple[int, int]:
    """The output pixels (start, stop) whose taps (``bounds``: first input and count, in order)
    reach an input pixel in ``first .. last``."""
    reach = np.flatnonzero((bounds[:, 0] <= last) & (bounds[:, 0] + bounds[:, 1] > first))
    return int(reach[0]), int(reach[-1]) + 1


def bilinear_blend(a: np.ndarray, b: np.ndarray, guide: np.ndarray,
                   window: tuple[int, int, int, int] | None = None) -> np.ndarray:
    """``clip(A guide + B, 0, 1)``, float32 (H, W), where ``A`` and ``B`` are ``a`` and ``b`` (h, w)
    float32 resized to the guide's (H, W) by :func:`resize_mask`'s bilinear resizing (Pillow's
    two-pass resampling as Pillow 13 does it: double sums, float32 between the passes, the reduced
    direction first, no pass where a size does not change: the same bits for finite maps; a NaN or
    infinite coefficient may spread differently where a direction is reduced), computed without
    making ``A`` and ``B`` (compiled; a quarter of the time).  ``window`` (y0, y1, x0, x1): only
    those rows and columns of it, the same values."""
    (h, w), (H, W) = a.shape, guide.shape
    if b.shape != a.shape:
        raise ValueError(f"a and b must have one shape, got {a.shape} and {b.shape}")
    y0, y1, x0, x1 = (0, H, 0, W) if window is None else window
    across, down = pillow_taps(w, W, "bilinear"), pillow_taps(h, H, "bilinear")
    out = np.empty((y1 - y0, x1 - x0), np.float32)
    _blend(np.ascontiguousarray(a, np.float32), np.ascontiguousarray(b, np.float32),
           np.ascontiguousarray(guide, np.float32), *across, *down, y0, x0, out)
    return out


@compiled
def _blend(a, b, guide, across_bounds, across, down_bounds, down, y0, x0, out) -> None:
    """:func:`bilinear_blend`'s rows ``y0 ..`` and columns ``x0 ..`` (as many as ``out`` holds)
    into ``out``, in Pillow's order of passes (down first where the rows are reduced, else across
    first; a direction whose size does not change has no pass), each tap sum in double from 0 in
    tap order and stored as float32, then blended row by row."""
    h, w = a.shape
    H, W = guide.shape
    rows, cols = out.shape
    sa = np.empty(max(w, W))
    sb = np.empty(max(w, W))
    if H < h:                                          # down first: (rows, w), then across and blend
        rows_a = np.empty((rows, w), np.float32)
        rows_b = np.empty((rows, w), np.float32)
        for r in range(rows):
            yy = y0 + r
            _down_row(a, b, down_bounds[yy, 0], down_bounds[yy, 1], down[yy], sa, sb)
            for x in range(w):
                rows_a[r, x] = sa[x]
                rows_b[r, x] = sb[x]
        for r in range(rows):
            for q in range(cols):
                xx = x0 + q
                if w == W:
                    va, vb = np.float64(rows_a[r, xx]), np.float64(rows_b[r, xx])
                else:
                    va, vb = _across(rows_a, rows_b, r, across_bounds[xx, 0], across_bounds[xx, 1], across[xx])
                out[r, q] = _blended(np.float32(va), np.float32(vb), guide[y0 + r, xx])
        return
    rows_a = np.empty((h, cols), np.float32)           # across first: (h, cols), then down and blend
    rows_b = np.empty((h, cols), np.float32)
    for y in range(h):
        for q in range(cols):
            xx = x0 + q
            if w == W:
                rows_a[y, q], rows_b[y, q] = a[y, xx], b[y, xx]
            else:
                rows_a[y, q], rows_b[y, q] = _across(a, b, y, across_bounds[xx, 0], across_bounds[xx, 1],
                                                     across[xx])
    for r in range(rows):
        yy = y0 + r
        if h == H:
            for q in range(cols):
                sa[q], sb[q] = rows_a[yy, q], rows_b[yy, q]
        else:
            _down_row(rows_a, rows_b, down_bounds[yy, 0], down_bounds[yy, 1], down[yy], sa, sb)
        for q in range(cols):
            out[r, q] = _blended(np.float32(sa[q]), np.float32(sb[q]), guide[yy, x0 + q])


@inlined
def _across(a, b, y: int, first: int, count: int, taps) -> tuple[float, float]:
    """The tap sums (double, from 0, in tap order) of columns ``first .. first + count`` of row
    ``y`` of ``a`` and of ``b``."""
    va = 0.0
    vb = 0.0
    for x in range(count):
        va += np.float64(a[y, first + x]) * taps[x]
        vb += np.float64(b[y, first + x]) * taps[x]
    return va, vb


@inlined
def _down_row(a, b, first: int, count: int, taps, sa, sb) -> None:
    """The tap sums (double, from 0, in tap order) of rows ``first .. first + count`` of ``a`` and
    ``b`` into ``sa`` and ``sb``, column by column."""
    n = a.shape[1]
    sa[:n] = 0.0
    sb[:n] = 0.0
    for y in range(count):
        k = taps[y]
        for x in range(n):
            sa[x] += np.float64(a[first + y, x]) * k
            sb[x] += np.float64(b[first + y, x]) * k


@inlined
def _blended(a, b, g):
    """``clip(a g + b, 0, 1)`` in float32 as NumPy computes it (NaN stays NaN)."""
    v = np.float32(a * g) + b
    if v < 0:
        return np.float32(0.0)
    if v > 1:
        return np.float32(1.0)
    return v


def to_image(rgb: np.ndarray, p: np.ndarray, spec: MaskSpec, guide: np.ndarray | None = None) -> np.ndarray:
    """An object probability ``p`` on a grid over the whole of ``rgb`` (the network's ``spec.size``
    square, or the image's own pixels) at the image's (H, W), float32 in [0, 1]: through
    ``spec``'s guided filter (its radius given in the network's pixels, scaled to the grid;
    ``guide``: :func:`guide_of` ``rgb`` when the caller has it), else resized (bilinear)."""
    p = np.asarray(p, np.float32)
    if spec.guide > 0:
        return guided_filter(rgb, p, spec.guide * max(p.shape) / spec.size, spec.guide_eps, guide)
    return np.clip(p if p.shape == rgb.shape[:2] else resize_mask(p, *rgb.shape[:2]), 0.0, 1.0)


def grown_box(box: tuple[int, int, int, int], height: int, width: int, margin: float) -> tuple[int, int, int, int]:
    """(top, left, bottom, right), exclusive: ``box`` (the same order) grown on each side by
    ``margin`` of its longest side (rounded to whole pixels), clipped to a height x width image."""
    top, left, bottom, right = box
    grow = int(round(margin * max(bottom - top, right - left)))
    return max(0, top - grow), max(0, left - grow), min(height, bottom + grow), min(width, right + grow)


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
    """(H, W) float32 object mask of an opaque image ``rgb`` ((H, W, 3|4) uint8, a view as it lies)
    from ``segment`` (the foreground network: an (h, w, 3|4) uint8 image to its object probability
    on a grid over the whole image, the network's ``spec.size`` square or the image's own pixels),
    brought to the image (:func:`to_image`: the guided filter of ``spec``), specks removed
    (:func:`clean_mask`; NoObjectError when nothing is left); a small object in a large photo is
    segmented again in its square (see :class:`MaskSpec`), the second mask replacing the first
    there and clearing it elsewhere (unless it finds nothing: then the first stands).  Where the
    second look is made, the first look's mask is made only on its :func:`first_look_window` (its
    box is the same) and whole only if the second look finds nothing.  ``refine`` (the refinement network: a
    (4, crop_size, crop_size) :func:`crop_input` to its object probability on that grid), when
    given and ``spec.crop_size`` is set, then segments the object's square once more
    (:func:`refined_mask`)."""
    h, w = rgb.shape[:2]
    guide = guide_of(rgb) if spec.guide > 0 else None          # one grey image for both looks
    p = segment(rgb)
    coefficients = blend_coefficients(p, spec, guide)          # made once, for the window and the whole

    def first_look() -> np.ndarray:
        whole = to_image(rgb, p, spec, guide) if coefficients is None else bilinear_blend(*coefficients, guide)
        return clean_mask(whole, spec)

    mask, box = None, None
    if coefficients is not None and spec.refine > 0:
        box = _first_box(coefficients, guide, spec)
    if box is None:
        mask = first_look()
        box = mask_bounds(mask > 0.5)
    square = refine_square(box, h, w, spec)
    if square is not None and min(square[1] - square[0], square[3] - square[2]) >= spec.refine_side:
        y0, y1, x0, x1 = square
        try:
            crop = rgb[y0:y1, x0:x1]
            part = clean_mask(to_image(crop, segment(crop), spec, None if guide is None else guide[y0:y1, x0:x1]),
                              spec, h * w)
            mask = np.zeros((h, w), np.float32)
            mask[y0:y1, x0:x1] = part
        except NoObjectError:            # the closer look lost the object: keep the first look's mask
            pass
    if mask is None:                     # the first look's mask was only made where it passes 0.5
        mask = first_look()
    if refine is None or not spec.crop_size:
        return mask
    return refined_mask(rgb, mask, refine, spec)


def _first_box(coefficients: tuple[np.ndarray, np.ndarray], guide: np.ndarray, spec: MaskSpec
               ) -> tuple[int, int, int, int] | None:
    """The box of the first look's cleaned mask (:func:`clean_mask` of the blend of
    ``coefficients``) from its :func:`first_look_window` only: the same box as from the whole mask
    (no value outside the window passes 0.5, and the clean-up judges only those that do).  None
    where the window is not known or the clean-up finds no object in it (the whole mask then says
    so)."""
    seen = first_look_window(*coefficients, guide)
    if seen is None:
        return None
    values, (y0, y1, x0, x1) = seen
    try:
        top, left, bottom, right = mask_bounds(clean_mask(values, spec, guide.shape[0] * guide.shape[1]) > 0.5)
    except NoObjectError:
        return None
    return top + y0, left + x0, bottom + y0, right + x0


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


def mask_confidence(mask: np.ndarray) -> float:
    """How sure a mask (H, W) in [0, 1] is where it matters, at its edge: the mean of |2 p - 1| over
    the pixels within a band about the 0.5 boundary (a square window of 1% of the mask's longest
    side, at least 2 pixels, each way); 1.0 for a crisp mask, near 0 for one that hesitates along
    its whole outline."""
    hard = mask > 0.5
    box = mask_bounds(hard)
    if box is None:
        return 0.0
    reach = max(2, round(0.01 * max(box[2] - box[0], box[3] - box[1])))
    top, left = max(0, box[0] - reach - 1), max(0, box[1] - reach - 1)       # the band lies about the box
    near, p = hard[top:box[2] + reach + 1, left:box[3] + reach + 1], mask[top:box[2] + reach + 1, left:box[3] + reach + 1]
    band = _edge_band(near, reach)
    return float(np.abs(2 * p[band] - 1).mean()) if band.any() else 1.0


@compiled
def _edge_band(hard: np.ndarray, reach: int) -> np.ndarray:
    """The pixels whose (2 reach + 1)² window holds pixels of ``hard`` and pixels not of it (those
    beyond the border count as not): ``maximum_filter(hard) > 0 & minimum_filter(hard, mode="constant")
    == 0`` of SciPy, by counts over a summed-area table."""
    h, w = hard.shape
    table = np.zeros((h + 1, w + 1), np.int64)
    for y in range(h):
        run = 0
        for x in range(w):
            run += hard[y, x]
            table[y + 1, x + 1] = table[y, x + 1] + run
    full = (2 * reach + 1) ** 2
    band = np.zeros((h, w), np.bool_)
    for y in range(h):
        y0, y1 = max(0, y - reach), min(h, y + reach + 1)
        for x in range(w):
            x0, x1 = max(0, x - reach), min(w, x + reach + 1)
            count = table[y1, x1] - table[y0, x1] - table[y1, x0] + table[y0, x0]
            band[y, x] = 0 < count < full
    return band


def mask_iou(ours: np.ndarray, truth: np.ndarray) -> float:
    """Intersection over union of two boolean masks (0 when both are empty)."""
    return float((ours & truth).sum() / max(1, (ours | truth).sum()))
