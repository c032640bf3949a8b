"""Photo-like composites of the dataset's renders: what a phone photo of the object looks like.

A render (RGBA, exact alpha) is placed at a random scale, offset and aspect ratio on a background
(a crop of a real photograph, or a procedural gradient, noise, texture, random shapes, gravel, print
or specks of light), under random lighting, with a soft shadow beneath the object, colour jitter of
object and scene, blur, sensor noise and JPEG compression.  The result has no alpha; the exact object mask comes with it.

Real photographs are scikit-image's sample images, split once: :data:`TRAIN_PHOTOS` for training,
:data:`TEST_PHOTOS`, never in training, for the fixed photo-like views of every split (none
shows one of the dataset's categories).  The foreground network trains on these composites, the
image model trains on them after the segmentation step, and :func:`photo_split_view` makes the
fixed photo-like view of a shape, so every consumer composes photos with this one module.
"""

from __future__ import annotations

import functools
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw, ImageFilter, ImageFont
from scipy import ndimage

from ..image.mask import grown_box, mask_bounds
from .render import render_views
from .shapes import CATEGORIES, generate, split_of, stable_hash

TRAIN_PHOTOS = ("astronaut.png", "chelsea.png", "coffee.png", "motorcycle_left.png", "brick.png", "grass.png",
                "camera.png", "coins.png", "moon.png", "page.png", "clock_motion.png", "ihc.png", "retina.jpg", "cell.png")
"""scikit-image sample photographs used as training backgrounds."""
TEST_PHOTOS = ("rocket.jpg", "gravel.png", "hubble_deep_field.jpg", "text.png")
"""Sample photographs kept out of training: the backgrounds of every split's fixed photo-like views
(:func:`photo_split_view`: the test split's and the held-out seed's, and the validation split's that
decisions are made on; the shapes of each split are their own, the four photographs are shared)."""
SPLITS = {"train": TRAIN_PHOTOS, "test": TEST_PHOTOS}
SCENES = ("gradient", "noise", "pattern", "shapes", "pebbles", "print", "specks")
"""The procedural scenes a background is drawn from, by name (the painters below)."""
FIRST_SCENES = SCENES[:4]
"""The procedural scenes of the first foreground networks' training and of the photo-like test
split (kept as it was measured)."""


@dataclass(frozen=True)
class PhotoStyle:
    """The ranges a composite is drawn from.

    ``scale``: the object's longest side as a share of the photo's short side; ``short_side``:
    the photo's short side in pixels; ``aspect``: long / short side; ``real``: the share of real
    photographs among backgrounds; ``cut``: the largest share of the object's box allowed to fall
    outside the photo; ``scenes``: the procedural scenes drawn from (names of :data:`SCENES`)."""

    scale: tuple[float, float] = (0.15, 0.95)
    short_side: tuple[int, int] = (160, 320)
    aspect: tuple[float, float] = (1.0, 1.6)
    real: float = 0.5
    shadow: float = 0.6
    jpeg: float = 0.7
    cut: float = 0.1
    scenes: tuple[str, ...] = SCENES


@dataclass
class Photo:
    """A composite: ``rgb`` (H, W, 3) uint8 without alpha; ``mask`` (H, W) float32 in [0, 1], the
    object's exact coverage of each pixel; ``box`` (top, left, bottom, right), exclusive, of the
    mask's pixels above 0.5 (None when the object fell outside the photo)."""

    rgb: np.ndarray
    mask: np.ndarray
    box: tuple[int, int, int, int] | None


@functools.cache
def real_photo(name: str) -> np.ndarray:
    """(H, W, 3) uint8 of a scikit-image sample photograph (a file of its data folder, installed
    with the package: nothing is downloaded)."""
    import skimage  # deferred: scikit-image is the train extra's, not a base dependency

    with Image.open(Path(skimage.__file__).parent / "data" / name) as img:
        return np.asarray(img.convert("RGB")).copy()


def background(rng: np.random.Generator, h: int, w: int, split: str = "train", real: float = 0.5,
               scenes: tuple[str, ...] = SCENES) -> np.ndarray:
    """(h, w, 3) floats in [0, 255]: a crop of a real photograph of ``split`` (share ``real``) or a
    procedural scene, one of ``scenes`` (names of :data:`SCENES`); then a random lighting ramp."""
    if rng.random() < real:
        names = SPLITS[split]
        src = real_photo(names[int(rng.integers(len(names)))])
        zoom = max(h / src.shape[0], w / src.shape[1]) * rng.uniform(1.0, 2.5)   # source pixels -> ours
        ch, cw = min(src.shape[0], round(h / zoom)), min(src.shape[1], round(w / zoom))
        y, x = int(rng.integers(src.shape[0] - ch + 1)), int(rng.integers(src.shape[1] - cw + 1))
        img = Image.fromarray(src[y:y + ch, x:x + cw]).resize((w, h), Image.Resampling.BILINEAR)
        if rng.random() < 0.5:
            img = img.transpose(Image.Transpose.FLIP_LEFT_RIGHT)
        if rng.random() < 0.5:                       # a shallow depth of field
            img = img.filter(ImageFilter.GaussianBlur(rng.uniform(1, 6)))
        bg = np.asarray(img, np.float32)
    else:
        kind = scenes[int(rng.integers(len(scenes)))]
        c0, c1 = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
        bg = _SCENE_PAINTERS[kind](rng, h, w, c0, c1)
    bg = np.asarray(bg, np.float32)
    light = _lighting(rng, h, w)
    return np.clip(bg * light[..., None], 0, 255)


def _gradient(rng: np.random.Generator, h: int, w: int, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """A smooth gradient in any direction: a studio backdrop."""
    yy, xx = (g.astype(np.float32) for g in np.ogrid[0:h, 0:w])
    t = rng.uniform(0, 2 * np.pi)
    ramp = (np.cos(t) * xx + np.sin(t) * yy)
    ramp = (ramp - ramp.min()) / max(1e-6, float(np.ptp(ramp)))
    return c0 * (1 - ramp[..., None]) + c1 * ramp[..., None]


def _noise(rng: np.random.Generator, h: int, w: int, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """Noise at several scales about one colour."""
    bg = np.broadcast_to(c0, (h, w, 3)).astype(np.float32).copy()
    for cell in (64, 16, 4):
        coarse = rng.normal(0, rng.uniform(5, 40), (h // cell + 2, w // cell + 2, 3)).astype(np.float32)
        bg += _resize3(coarse, h, w)
    return bg


def _pattern(rng: np.random.Generator, h: int, w: int, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """Stripes or checks: fabric, tiles, wood."""
    yy, xx = (g.astype(np.float32) for g in np.ogrid[0:h, 0:w])
    period = rng.uniform(4, 40)
    t = rng.uniform(0, np.pi)
    u = (np.cos(t) * xx + np.sin(t) * yy) / period
    v = (-np.sin(t) * xx + np.cos(t) * yy) / period
    pattern = np.sin(2 * np.pi * u) if rng.random() < 0.5 else np.sign(np.sin(np.pi * u) * np.sin(np.pi * v))
    pattern = (pattern + 1) / 2
    return c0 * (1 - pattern[..., None]) + c1 * pattern[..., None]


def _shapes(rng: np.random.Generator, h: int, w: int, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """Random rectangles and ellipses on a colour: a cluttered scene."""
    img = Image.new("RGB", (w, h), tuple(int(c) for c in c0))
    draw = ImageDraw.Draw(img)
    for _ in range(int(rng.integers(3, 15))):
        x0, y0 = rng.uniform(-0.2, 1.0) * w, rng.uniform(-0.2, 1.0) * h
        x1, y1 = x0 + rng.uniform(0.05, 0.6) * w, y0 + rng.uniform(0.05, 0.6) * h
        fill = tuple(int(c) for c in rng.uniform(0, 255, 3))
        (draw.ellipse if rng.random() < 0.5 else draw.rectangle)((x0, y0, x1, y1), fill=fill)
    if rng.random() < 0.5:
        img = img.filter(ImageFilter.GaussianBlur(rng.uniform(0.5, 4)))
    return np.asarray(img, np.float32)


def _pebbles(rng: np.random.Generator, h: int, w: int, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """Densely packed small stones of tones between two colours, dark gaps between them: gravel,
    pebbles, a cobbled floor."""
    img = Image.new("RGB", (w, h), tuple(int(c) for c in c0 * rng.uniform(0.2, 0.7)))
    draw = ImageDraw.Draw(img)
    r = rng.uniform(2, 14)                                      # the stones' mean radius, pixels
    n = min(8000, int(h * w / (r * r * 2.2)))
    centres = rng.uniform(0, 1, (n, 2)) * (w, h)
    radii = r * rng.uniform(0.5, 1.5, (n, 2))
    t = rng.uniform(0, 1, (n, 1))
    tones = np.clip(c0 * (1 - t) + c1 * t + rng.normal(0, 25, (n, 1)), 0, 255).astype(int)
    for (cx, cy), (rx, ry), tone in zip(centres, radii, tones):
        draw.ellipse((cx - rx, cy - ry, cx + rx, cy + ry), fill=tuple(tone))
    if rng.random() < 0.7:
        img = img.filter(ImageFilter.GaussianBlur(rng.uniform(0.3, 1.5)))
    bg = np.asarray(img, np.float32)
    grey = bg.mean(axis=-1, keepdims=True)                      # stones are mostly dull, and grainy
    bg = grey + (bg - grey) * np.float32(rng.uniform(0.1, 1.0))
    return bg + rng.normal(0, rng.uniform(3, 20), (h, w, 1)).astype(np.float32)


@functools.cache
def _font(size: int) -> ImageFont.FreeTypeFont | ImageFont.ImageFont:
    return ImageFont.load_default(size)


_GLYPHS = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789      .,;:-()"


def _print(rng: np.random.Generator, h: int, w: int, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """Lines of text and pen strokes on paper (or light on dark): a page, a sign, a whiteboard."""
    paper = 255 - (255 - c0) * rng.uniform(0, 0.4)
    ink = c1 * rng.uniform(0, 0.4)
    if rng.random() < 0.25:
        paper, ink = ink, paper
    paper_t, ink_t = tuple(int(c) for c in paper), tuple(int(c) for c in ink)
    img = Image.new("RGB", (w, h), paper_t)
    draw = ImageDraw.Draw(img)
    size = int(rng.integers(8, 49))
    font = _font(size)
    step = size * rng.uniform(1.1, 2.2)
    y = rng.uniform(-size, step)
    while y < h:
        chars = rng.integers(len(_GLYPHS), size=int(rng.integers(5, 80)))
        draw.text((rng.uniform(-0.1, 0.3) * w, y), "".join(_GLYPHS[c] for c in chars), fill=ink_t, font=font)
        y += step
    for _ in range(int(rng.integers(0, 6))):                     # handwriting, underlines, doodles
        pts = np.cumsum(rng.normal(0, 0.15, (int(rng.integers(2, 10)), 2)), axis=0) + rng.uniform(0, 1, 2)
        draw.line([(x * w, y * h) for x, y in pts], fill=ink_t, width=int(rng.integers(1, 7)))
    if rng.random() < 0.5:
        img = img.rotate(rng.uniform(-30, 30), resample=Image.Resampling.BILINEAR, fillcolor=paper_t)
    return np.asarray(img, np.float32)


def _specks(rng: np.random.Generator, h: int, w: int, c0: np.ndarray, c1: np.ndarray) -> np.ndarray:
    """Bright points and soft smudges on a dark ground: a night sky, city lights, sparkle, dust."""
    light = np.zeros((h, w), np.float32)
    n = int(h * w * rng.uniform(0.0005, 0.01))
    light[rng.integers(0, h, n), rng.integers(0, w, n)] = rng.pareto(1.5, n).astype(np.float32) + 0.3
    light = ndimage.gaussian_filter(light, rng.uniform(0.4, 1.5)) * 4
    for _ in range(int(rng.integers(0, 6))):                    # a few large faint glows
        glow = np.zeros((h, w), np.float32)
        glow[int(rng.integers(h)), int(rng.integers(w))] = 1
        sigma = rng.uniform(3, 20)
        light += ndimage.gaussian_filter(glow, sigma) * (2 * np.pi * sigma ** 2) * rng.uniform(0.1, 0.6)
    tint = 0.5 + 0.5 * c1 / 255
    return c0 * rng.uniform(0, 0.2) + np.clip(light, 0, 1.2)[..., None] * (255 * tint)


_SCENE_PAINTERS = {"gradient": _gradient, "noise": _noise, "pattern": _pattern, "shapes": _shapes,
                   "pebbles": _pebbles, "print": _print, "specks": _specks}


def _resize3(a: np.ndarray, h: int, w: int) -> np.ndarray:
    return np.stack([np.asarray(Image.fromarray(a[..., c]).resize((w, h), Image.Resampling.BICUBIC))
                     for c in range(3)], axis=2)


def _lighting(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    """(h, w) gain: a linear ramp and a vignette of random strength around a random centre."""
    yy, xx = (g.astype(np.float32) for g in np.ogrid[0:h, 0:w])
    t = rng.uniform(0, 2 * np.pi)
    ramp = (np.cos(t) * (xx / w - 0.5) + np.sin(t) * (yy / h - 0.5)) * rng.uniform(0, 0.6)
    cy, cx = rng.uniform(0.2, 0.8) * h, rng.uniform(0.2, 0.8) * w
    r2 = ((yy - cy) / h) ** 2 + ((xx - cx) / w) ** 2
    return (rng.uniform(0.6, 1.3) + ramp) * (1 - rng.uniform(0, 0.8) * np.clip(r2, 0, 1))


def object_crop(rgba: np.ndarray) -> np.ndarray:
    """The render cropped to its alpha's bounding box (ValueError when the render is empty)."""
    a = rgba[..., 3]
    rows, cols = np.flatnonzero(a.any(axis=1)), np.flatnonzero(a.any(axis=0))
    if len(rows) == 0:
        raise ValueError("the render has no opaque pixel")
    return rgba[rows[0]:rows[-1] + 1, cols[0]:cols[-1] + 1]


def _jitter(rgb: np.ndarray, rng: np.random.Generator, strength: float) -> np.ndarray:
    """Brightness, contrast, saturation and per-channel gain jitter of float RGB in [0, 255]."""
    grey = rgb.mean(axis=-1, keepdims=True)
    sat = np.float32(rng.uniform(1 - 0.6 * strength, 1 + 0.5 * strength))
    contrast = np.float32(rng.uniform(1 - 0.4 * strength, 1 + 0.3 * strength))
    gain = (rng.uniform(1 - 0.35 * strength, 1 + 0.25 * strength)
            * rng.uniform(1 - 0.1 * strength, 1 + 0.1 * strength, 3)).astype(np.float32)
    mean = np.float32(grey.mean())
    # saturation about the grey, contrast about the mean, then a gain per channel
    return ((grey - mean) * contrast + mean + (rgb - grey) * (sat * contrast)) * gain


def photo_composite(rgba: np.ndarray, rng: np.random.Generator, split: str = "train",
                    style: PhotoStyle = PhotoStyle()) -> Photo:
    """A photo-like composite of one render (see the module docstring) and its exact mask."""
    obj = object_crop(np.asarray(rgba))
    short = int(rng.integers(style.short_side[0], style.short_side[1] + 1))
    long = int(round(short * rng.uniform(*style.aspect)))
    h, w = (short, long) if rng.random() < 0.5 else (long, short)
    target = rng.uniform(*style.scale) * short                  # the object's longest side, pixels
    f = target / max(obj.shape[:2])
    oh, ow = max(1, round(obj.shape[0] * f)), max(1, round(obj.shape[1] * f))
    placed = Image.fromarray(np.ascontiguousarray(obj), "RGBA").convert("RGBa")
    placed = np.asarray(placed.resize((ow, oh), Image.Resampling.BILINEAR if f > 1 else Image.Resampling.BOX)
                        .convert("RGBA"), np.float32)
    # the object's top-left corner: anywhere that keeps at least 1 - cut of its box in the photo
    my, mx = style.cut * oh, style.cut * ow
    y0 = int(round(rng.uniform(-my, max(-my, h - oh + my))))
    x0 = int(round(rng.uniform(-mx, max(-mx, w - ow + mx))))
    alpha = np.zeros((h, w), np.float32)
    colour = np.zeros((h, w, 3), np.float32)
    ys, ye, xs, xe = max(0, y0), min(h, y0 + oh), max(0, x0), min(w, x0 + ow)
    if ye > ys and xe > xs:
        part = placed[ys - y0:ye - y0, xs - x0:xe - x0]
        alpha[ys:ye, xs:xe] = part[..., 3] / 255.0
        colour[ys:ye, xs:xe] = part[..., :3]
    scene = background(rng, h, w, split, style.real, style.scenes)
    if rng.random() < style.shadow:                             # a soft contact shadow under the object
        scene *= 1 - _shadow(alpha, rng)[..., None]
    scene = _jitter(scene, rng, 1.0)
    rgb = scene
    if ye > ys and xe > xs:                                     # the object, jittered, over the scene
        a = alpha[ys:ye, xs:xe, None]
        rgb[ys:ye, xs:xe] = _jitter(colour[ys:ye, xs:xe], rng, 0.7) * a + scene[ys:ye, xs:xe] * (1 - a)
    if rng.random() < 0.3:
        rgb = np.asarray(Image.fromarray(np.clip(rgb, 0, 255).astype(np.uint8)).filter(
            ImageFilter.GaussianBlur(rng.uniform(0.3, 1.2))), np.float32)
    rgb += rng.standard_normal(rgb.shape, dtype=np.float32) * np.float32(rng.uniform(0, 6))   # sensor noise
    out = np.clip(np.round(rgb), 0, 255).astype(np.uint8)
    if rng.random() < style.jpeg:
        buf = io.BytesIO()
        Image.fromarray(out).save(buf, "JPEG", quality=int(rng.integers(35, 96)))
        out = np.asarray(Image.open(io.BytesIO(buf.getvalue())).convert("RGB"))
    return Photo(out, alpha, mask_box(alpha))


def _shadow(alpha: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """(H, W) darkening in [0, 1): a blurred ellipse at the object's base, or its blurred silhouette
    pushed down and to the side."""
    h, w = alpha.shape
    box = mask_box(alpha)
    if box is None:
        return np.zeros_like(alpha)
    top, left, bottom, right = box
    img = Image.new("F", (w, h), 0.0)
    if rng.random() < 0.6:
        cx, half = (left + right) / 2, (right - left) / 2 * rng.uniform(0.7, 1.3)
        tall = max(2.0, (bottom - top) * rng.uniform(0.05, 0.2))
        ImageDraw.Draw(img).ellipse((cx - half, bottom - tall, cx + half, bottom + tall), fill=1.0)
    else:
        dy, dx = int((bottom - top) * rng.uniform(0.02, 0.15)), int((right - left) * rng.uniform(-0.2, 0.2))
        img = Image.fromarray(np.roll(alpha, (dy, dx), axis=(0, 1)).astype(np.float32), "F")
    radius = max(1.0, (right - left) * rng.uniform(0.03, 0.15))
    return np.clip(_blur_support(np.asarray(img, np.float32), radius), 0, 1) * rng.uniform(0.2, 0.6)


def _blur_support(a: np.ndarray, sigma: float) -> np.ndarray:
    """``ndimage.gaussian_filter(a, sigma)``, computed only about where ``a`` is not zero: the
    kernel (4 sigma a side) reaches no further, and a margin of zeros reflects as zeros, so the
    result is the same to the bit."""
    box = mask_bounds(a != 0)
    if box is None:
        return np.zeros_like(a)
    reach = int(BLUR_TRUNCATE * sigma + 0.5) + 1
    top, left = max(0, box[0] - reach), max(0, box[1] - reach)
    bottom, right = min(a.shape[0], box[2] + reach), min(a.shape[1], box[3] + reach)
    out = np.zeros_like(a)
    out[top:bottom, left:right] = ndimage.gaussian_filter(a[top:bottom, left:right], sigma, truncate=BLUR_TRUNCATE)
    return out


BLUR_TRUNCATE = 4.0
"""Where :func:`_blur_support`'s Gaussian is cut, in sigmas (scipy's default, which it reproduces)."""


def mask_box(mask: np.ndarray, level: float = 0.5) -> tuple[int, int, int, int] | None:
    """(top, left, bottom, right), exclusive, of the pixels of ``mask`` above ``level``; None if none."""
    return mask_bounds(mask > level)


TEST_STYLE = PhotoStyle(scale=(0.3, 0.95), scenes=FIRST_SCENES)
"""The photo-like test split: objects as a user photographs them (their longest side 30-95% of the
photo's short side; training also sees them down to 15%)."""


def photo_split_view(images: np.ndarray, shape_id: str) -> Photo:
    """The photo-like test view of a shape: a fixed render (by the shape's id) composited with
    :data:`TEST_PHOTOS` in :data:`TEST_STYLE` with a fixed seed, so every evaluation sees the same
    photo."""
    seed = stable_hash("photo-split", shape_id)
    view = seed % len(images)
    return photo_composite(images[view], np.random.default_rng(seed), "test", TEST_STYLE)


def generated_photos(per_category: int = 2, views: int = 2, seed: int = 0,
                     style: PhotoStyle = PhotoStyle(scenes=FIRST_SCENES), split: str = "train") -> list[Photo]:
    """Training-like photos without a dataset: the generator's first ``per_category`` shapes of
    ``split`` in every category (dataset seed 0), each rendered from ``views`` random viewpoints as
    the dataset renders them and composited on training backgrounds in ``style``, all drawn from
    ``seed``.  What the export calibrates a quantised foreground network with (by default on the
    scenes the shipped network was trained on, so that its int8 graph is made again bit for bit)."""

    rng = np.random.default_rng(seed)
    photos = []
    for category in CATEGORIES:
        indices = (i for i in range(10 ** 6) if split_of(category, i) == split)
        for _, index in zip(range(per_category), indices):
            images, _ = render_views(generate(category, index), n_views=views, rng=rng)
            photos += [photo_composite(image, rng, "train", style) for image in images]
    return photos


PROMPT_MARGIN = 0.05
"""A box prompt as a user drags it: the object's box grown by this share of its longest side on
each side (not pixel-exact), clipped to the photo."""


def box_prompt(mask: np.ndarray, margin: float = PROMPT_MARGIN) -> tuple[int, int, int, int] | None:
    """The box prompt (left, top, right, bottom: the service's ``box=``) about the object of an
    exact mask (H, W) (coverage above 0.5), grown by ``margin`` of its longest side and clipped to
    the photo; None when the object is not in the photo."""
    box = mask_box(mask)
    if box is None:
        return None
    top, left, bottom, right = grown_box(box, *mask.shape, margin)
    return left, top, right, bottom


def with_alpha(rgb: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """(H, W, 4) uint8: the photo with its exact mask (coverage in [0, 1]) as alpha, what a perfect
    foreground network would give."""
    return np.dstack([rgb, np.round(np.clip(mask, 0, 1) * 255).astype(np.uint8)])


ENCODER_STYLE = PhotoStyle(scale=(0.35, 0.95), short_side=(200, 320))
"""The composites the image model trains on: objects large enough that the crop keeps detail."""


def imperfect_mask(mask: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A copy of an exact mask with the mistakes a foreground network makes: a boundary grown or
    shrunk by up to 3 pixels, blur, sometimes a blob of residual background beside the object or
    a bite out of it."""
    m = np.asarray(mask, np.float32)
    k = int(rng.integers(-3, 4))
    if k > 0:
        m = ndimage.grey_dilation(m, size=(2 * k + 1, 2 * k + 1))
    elif k < 0:
        m = ndimage.grey_erosion(m, size=(-2 * k + 1, -2 * k + 1))
    if rng.random() < 0.5:
        m = ndimage.gaussian_filter(m, rng.uniform(0.5, 2.0))
    box = mask_box(mask)
    if box is not None:
        top, left, bottom, right = box
        for value, p in ((1.0, 0.3), (0.0, 0.2)):              # residual background; a missed part
            if rng.random() < p:
                h, w = bottom - top, right - left
                cy = rng.uniform(top - 0.2 * h, bottom + 0.2 * h)
                cx = rng.uniform(left - 0.2 * w, right + 0.2 * w)
                ry, rx = rng.uniform(0.05, 0.25) * h + 1, rng.uniform(0.05, 0.25) * w + 1
                yy, xx = np.ogrid[0:m.shape[0], 0:m.shape[1]]
                m[((yy - cy) / ry) ** 2 + ((xx - cx) / rx) ** 2 <= 1] = value
    return np.clip(m, 0, 1)
