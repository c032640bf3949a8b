"""The foreground network's input made in one compiled pass, against Pillow's resizing and NumPy's
normalisation bit for bit."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image

from model.image.resample import box_input, box_taps

MEAN = np.asarray((0.5, 0.45, 0.4), np.float32)
STD = np.asarray((0.25, 0.2, 0.3), np.float32)


def pillow_input(rgb: np.ndarray, size: int) -> np.ndarray:
    img = Image.fromarray(np.ascontiguousarray(rgb[..., :3]), "RGB").resize((size, size), Image.Resampling.BOX)
    x = np.asarray(img, np.float32) / 255.0
    return np.ascontiguousarray(((x - MEAN) / STD).transpose(2, 0, 1))


def sizes(rng: np.random.Generator, size: int) -> list[tuple[int, int]]:
    """Heights and widths at least ``size``: square, at random, and about where Pillow's order of
    passes switches (down first from h > 2 w - size)."""
    out = [(size, size), (size, 3 * size + 1), (3 * size + 1, size), (2 * size, 2 * size)]
    for _ in range(6):
        w = int(rng.integers(size, 4 * size))
        out += [(2 * w - size, w), (2 * w - size + 1, w), (int(rng.integers(size, 8 * size)), w)]
    return out


@pytest.mark.parametrize("size", [32, 64, 128])
def test_box_input_is_pillows_box_resize_and_the_normalisation(size):
    rng = np.random.default_rng(size)
    for h, w in sizes(rng, size):
        pixels = rng.integers(0, 256, (h + 3, w + 5, 4), dtype=np.uint8)
        views = (np.ascontiguousarray(pixels[:h, :w, :3]), pixels[:h, :w], pixels[2:2 + h, 3:3 + w],
                 pixels[h - 1::-1, :w], pixels[:h, w - 1::-1, :3])               # and reversed rows or columns
        for image in views:
            got = box_input(image, size, MEAN, STD)
            want = pillow_input(image, size)
            assert got.dtype == np.float32 and got.shape == (3, size, size)
            assert np.array_equal(got.view(np.uint32), want.view(np.uint32)), (h, w, image.shape, image.strides)


def test_box_input_keeps_flat_and_extreme_images_exact():
    for value in (0, 1, 127, 254, 255):
        image = np.full((301, 177, 3), value, np.uint8)
        assert np.array_equal(box_input(image, 64, MEAN, STD), pillow_input(image, 64))
    stripes = np.zeros((640, 480, 3), np.uint8)
    stripes[:, ::2] = 255                                 # every sum on the edge of its rounding
    assert np.array_equal(box_input(stripes, 128, MEAN, STD), pillow_input(stripes, 128))


def test_box_taps_sum_to_pillows_fixed_point_one():
    for n, out in ((640, 128), (129, 128), (128, 128), (1000, 7)):
        bounds, weights = box_taps(n, out)
        assert bounds[0, 0] == 0 and bounds[-1].sum() == n
        assert np.all(np.abs(weights.sum(axis=1) - (1 << 22)) <= weights.shape[1])


def test_box_input_refuses_what_it_does_not_reduce():
    with pytest.raises(ValueError, match="sides >= 64"):
        box_input(np.zeros((63, 200, 3), np.uint8), 64, MEAN, STD)
    with pytest.raises(ValueError, match="uint8"):
        box_input(np.zeros((100, 100, 3), np.float32), 64, MEAN, STD)
    with pytest.raises(ValueError, match=r"\(H, W, 3\|4\) uint8 image of sides >= 64, got uint8 \(100, 100\)"):
        box_input(np.zeros((100, 100), np.uint8), 64, MEAN, STD)
