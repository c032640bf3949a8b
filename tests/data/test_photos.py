"""Photo-like composites: the mask is exactly where the object was put, the ranges hold, the test
split's backgrounds are the held-out photographs only, and the degraded masks stay near the truth."""

from __future__ import annotations

import numpy as np
import pytest

from model.data import photos
from model.data.photos import (
    TEST_PHOTOS,
    TRAIN_PHOTOS,
    PhotoStyle,
    box_prompt,
    imperfect_mask,
    mask_box,
    object_crop,
    photo_composite,
    photo_split_view,
    real_photo,
)


def render(h: int = 120, w: int = 90) -> np.ndarray:
    """A synthetic RGBA render: an opaque red h x w rectangle."""
    rgba = np.zeros((137, 137, 4), np.uint8)
    rgba[10:10 + h, 20:20 + w] = (200, 30, 30, 255)
    return rgba


def test_photo_has_no_alpha_and_the_mask_is_the_placed_object():
    rgba = render()
    for seed in range(20):
        p = photo_composite(rgba, np.random.default_rng(seed), style=PhotoStyle(cut=0.0))
        assert p.rgb.dtype == np.uint8 and p.rgb.ndim == 3 and p.rgb.shape[2] == 3
        assert p.mask.shape == p.rgb.shape[:2]
        assert 0 <= p.mask.min() and p.mask.max() <= 1
        top, left, bottom, right = p.box
        short = min(p.rgb.shape[:2])
        longest = max(bottom - top, right - left)
        # the object's longest side is drawn from 15-95% of the short side (cut=0: wholly inside)
        assert 0.15 * short - 2 <= longest <= 0.95 * short + 2
        # its area is the rectangle's at the drawn scale: the mask covers exactly the object
        scale = longest / 120
        assert abs(p.mask.sum() - 120 * 90 * scale ** 2) <= 0.06 * 120 * 90 * scale ** 2 + 2 * longest


def test_the_object_keeps_its_colour_under_the_mask_and_the_scene_differs():
    rgba = render()
    p = photo_composite(rgba, np.random.default_rng(3), style=PhotoStyle(jpeg=0.0, cut=0.0))
    inside = p.rgb[p.mask > 0.99].astype(float)
    # red dominates inside the object despite jitter and noise; the scene is not the object's colour
    assert (inside[:, 0] - inside[:, 1:].max(1)).mean() > 60
    outside = p.rgb[p.mask < 0.01].astype(float)
    assert np.abs(outside.mean(0) - inside.mean(0)).max() > 10


def test_same_seed_same_photo_and_the_split_view_is_fixed():
    rgba = render()
    a = photo_composite(rgba, np.random.default_rng(7))
    b = photo_composite(rgba, np.random.default_rng(7))
    assert np.array_equal(a.rgb, b.rgb) and np.array_equal(a.mask, b.mask)
    views = np.stack([render(), render(60, 100)])
    assert np.array_equal(photo_split_view(views, "x1").rgb, photo_split_view(views, "x1").rgb)
    assert not np.array_equal(photo_split_view(views, "x1").rgb, photo_split_view(views, "x2").rgb)


def test_the_test_split_uses_only_held_out_photographs(monkeypatch):
    assert not set(TRAIN_PHOTOS) & set(TEST_PHOTOS)
    used = []
    monkeypatch.setattr(photos, "real_photo", lambda name: used.append(name) or np.zeros((300, 400, 3), np.uint8))
    for seed in range(40):
        photo_composite(render(), np.random.default_rng(seed), "test", PhotoStyle(real=1.0))
    assert used and set(used) <= set(TEST_PHOTOS)
    used.clear()
    for seed in range(40):
        photo_composite(render(), np.random.default_rng(seed), "train", PhotoStyle(real=1.0))
    assert used and set(used) <= set(TRAIN_PHOTOS)


@pytest.mark.parametrize("name", TRAIN_PHOTOS + TEST_PHOTOS)
def test_every_photograph_loads_offline(name):
    img = real_photo(name)
    assert img.dtype == np.uint8 and img.shape[2] == 3 and min(img.shape[:2]) >= 150


def test_imperfect_masks_stay_near_the_truth():
    truth = np.zeros((200, 200), np.float32)
    truth[50:150, 60:140] = 1
    ious = []
    for seed in range(30):
        m = imperfect_mask(truth, np.random.default_rng(seed))
        assert m.shape == truth.shape and 0 <= m.min() and m.max() <= 1
        a, b = m > 0.5, truth > 0.5
        ious.append((a & b).sum() / (a | b).sum())
    # mistakes of a few pixels and a blob now and then: imperfect, never unrelated
    assert min(ious) > 0.6 and np.mean(ious) < 0.99


def test_object_crop_and_box():
    rgba = render()
    assert object_crop(rgba).shape[:2] == (120, 90)
    assert mask_box(rgba[..., 3] / 255.0) == (10, 20, 130, 110)
    assert mask_box(np.zeros((5, 5))) is None
    with pytest.raises(ValueError):
        object_crop(np.zeros((8, 8, 4), np.uint8))


def test_generated_photos_show_training_shapes_of_every_category_on_training_scenes(monkeypatch):
    """The export's calibration photos need no dataset: every category's training shapes, rendered
    and composited on training backgrounds only, the same for the same seed."""
    from model.data.shapes import CATEGORIES, split_of
    from model.data.shapes import generate as real_generate

    shapes, used = [], []
    monkeypatch.setattr(photos, "generate",
                        lambda c, i, seed=0: shapes.append((c, i, seed)) or real_generate(c, i, seed))
    monkeypatch.setattr(photos, "real_photo", lambda name: used.append(name) or np.zeros((300, 400, 3), np.uint8))
    got = photos.generated_photos(per_category=1, views=2, seed=3)
    assert len(got) == 2 * len(CATEGORIES) and len(shapes) == len(CATEGORIES)
    assert {c for c, _, _ in shapes} == set(CATEGORIES)
    assert all(split_of(c, i) == "train" and seed == 0 for c, i, seed in shapes)
    assert set(used) <= set(TRAIN_PHOTOS)
    for p in got:
        assert p.rgb.ndim == 3 and p.rgb.shape[2] == 3 and p.box is not None and 0 < p.mask.mean() < 1
    again = photos.generated_photos(per_category=1, views=2, seed=3)
    assert all(np.array_equal(a.rgb, b.rgb) for a, b in zip(got, again))


@pytest.mark.parametrize("scene", photos.SCENES)
def test_every_procedural_scene_paints_a_textured_photo_of_the_asked_size(scene):
    """Each scene fills (h, w, 3) within [0, 255], is not flat, and differs from seed to seed."""
    h, w = 150, 230
    a = photos.background(np.random.default_rng(1), h, w, real=0.0, scenes=(scene,))
    b = photos.background(np.random.default_rng(2), h, w, real=0.0, scenes=(scene,))
    assert a.shape == (h, w, 3) and np.issubdtype(a.dtype, np.floating)
    assert a.min() >= 0 and a.max() <= 255
    assert a.std() > 2 and np.abs(a - b).mean() > 2


def test_pebbles_print_and_specks_have_the_texture_they_are_named_for():
    rng = np.random.default_rng(0)
    edges = {}
    for scene in ("gradient", "pebbles"):
        g = np.mean([photos._SCENE_PAINTERS[scene](np.random.default_rng(s), 200, 200, np.full(3, 90.0),
                                                  np.full(3, 200.0)).mean(-1) for s in range(4)], axis=0)
        edges[scene] = np.abs(np.diff(g, axis=1)).mean()
    assert edges["pebbles"] > 5 * edges["gradient"]           # stones: edges everywhere, a gradient none
    page = photos._print(rng, 200, 300, np.full(3, 250.0), np.full(3, 0.0)).mean(-1)
    light = page > 128
    assert 0.02 < (~light).mean() < 0.6 or 0.02 < light.mean() < 0.6   # thin strokes on a ground
    sky = photos._specks(rng, 200, 300, np.full(3, 20.0), np.full(3, 255.0)).mean(-1)
    assert np.median(sky) < 40 and sky.max() > 150            # bright points on a dark ground


def test_the_test_split_is_drawn_from_the_scenes_it_was_measured_with():
    assert photos.TEST_STYLE.scenes == photos.FIRST_SCENES == ("gradient", "noise", "pattern", "shapes")
    assert set(photos.PhotoStyle().scenes) == set(photos.SCENES) == set(photos._SCENE_PAINTERS)


def test_the_shadow_blur_about_its_support_is_the_whole_images_blur_to_the_bit():
    from scipy import ndimage

    from model.data.photos import _blur_support

    rng = np.random.default_rng(0)
    for k in range(60):
        h, w = (int(v) for v in rng.integers(8, 200, 2))
        a = np.zeros((h, w), np.float32)
        y, x = int(rng.integers(h)), int(rng.integers(w))
        part = a[y:y + int(rng.integers(1, h)), x:x + int(rng.integers(1, w))]
        part[...] = rng.uniform(0.1, 1) if k % 2 else rng.uniform(-1, 1, part.shape)
        sigma = float(rng.uniform(0.5, 25)) if k % 3 else float(rng.uniform(0.01, 0.5))
        assert np.array_equal(_blur_support(a, sigma), ndimage.gaussian_filter(a, sigma))
    assert not _blur_support(np.zeros((5, 7), np.float32), 3.0).any()


def test_a_box_prompt_is_the_objects_box_a_little_larger_clipped_to_the_photo():
    m = np.zeros((100, 200), np.float32)
    m[20:60, 50:130] = 1                                 # 40 rows x 80 columns: grown by 4 pixels
    assert box_prompt(m) == (46, 16, 134, 64)            # left, top, right, bottom (the service's box=)
    assert box_prompt(m, margin=0.0) == (50, 20, 130, 60)
    m[:] = 0
    m[0:30, 180:200] = 0.8                               # against the corner: clipped
    assert box_prompt(m, margin=0.5) == (165, 0, 200, 45)
    assert box_prompt(np.full((10, 10), 0.4, np.float32)) is None      # no pixel above half coverage
