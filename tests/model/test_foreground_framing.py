"""Background removal in the shared preprocessing: which mask is used, specks, no object, the crop
and the framing ratio, and the foreground network's input and output mapping."""

from __future__ import annotations

import numpy as np
import pytest
from PIL import Image
from scipy import ndimage

from model.image.decode import ImageError
from model.image.frame import MIN_OBJECT_SIDE, ImageSpec, frame_object
from model.image.mask import (
    FIRST_LOOK_WINDOW,
    MaskSpec,
    NoObjectError,
    bilinear_blend,
    blend_coefficients,
    clean_mask,
    cross_dilation,
    first_look_window,
    guide_of,
    mask_bounds,
    mask_confidence,
    mask_input,
    mask_output,
    object_mask,
    object_square,
    resize_mask,
    to_image,
)

SPEC = ImageSpec(size=64)


OBJECT = (20, 40, 160)


def photo(h=120, w=200, boxes=((30, 120, 90, 170),)) -> tuple[np.ndarray, np.ndarray]:
    """An opaque noisy bright scene with dark blue objects at ``boxes`` (off-centre), and their mask."""
    rng = np.random.default_rng(0)
    rgb = (rng.uniform(120, 255, (h, w, 3))).astype(np.uint8)
    mask = np.zeros((h, w), np.float32)
    for t, l, b, r in boxes:
        rgb[t:b, l:r] = OBJECT
        mask[t:b, l:r] = 1
    return rgb, mask


class Net:
    """A stand-in foreground network: the object's colour, on whatever image (or crop) it is given."""

    def __init__(self):
        self.calls = []

    def __call__(self, rgb):
        assert rgb.ndim == 3 and rgb.shape[2] in (3, 4)           # colour, or RGBA as the photo lies
        self.calls.append(rgb.shape[:2])
        return (np.abs(rgb[..., :3].astype(np.int32) - OBJECT).max(axis=2) < 30).astype(np.float32)


def extent(x: np.ndarray, spec: ImageSpec = SPEC) -> tuple[int, int]:
    """Rows and columns of the encoder input that are not the white background."""
    rgb = x.transpose(1, 2, 0) * np.asarray(spec.std) + np.asarray(spec.mean)
    obj = (rgb < 0.9).any(axis=2)
    return int(obj.any(1).sum()), int(obj.any(0).sum())


def test_an_opaque_photo_is_cut_out_with_the_networks_mask_and_framed():
    rgb, mask = photo()
    net = Net()
    f = frame_object(rgb, SPEC, net)
    # the object's square (84 px) is under half the photo but smaller than the network's input
    # (128 px): no second pass, which would see it enlarged and blurred
    assert net.calls == [(120, 200)] and f.mask_source == "network"
    assert f.box == (30, 120, 90, 170) and np.array_equal(f.mask > 127, mask > 0.5)
    assert f.mask.shape == rgb.shape[:2] and f.mask.dtype == np.uint8
    # the object, 60 x 50, fills the square's side in its longest direction at the spec's ratio (0.9)
    rows, cols = extent(f.image)
    assert abs(rows - 0.9 * 64) <= 2 and abs(cols - 0.9 * 64 * 50 / 60) <= 2
    # the scene is gone: everything outside the object is the encoder's white
    rgb_in = f.image.transpose(1, 2, 0) * 0.25 + 0.5
    assert (rgb_in[0, 0] > 0.97).all() and (rgb_in[-1, -1] > 0.97).all()


def test_without_the_network_the_scene_stays():
    rgb, mask = photo()
    for f in (frame_object(rgb, SPEC, None), frame_object(rgb, SPEC, Net(), "false")):
        assert f.mask_source == "none" and f.mask is None
        rgb_in = f.image.transpose(1, 2, 0) * 0.25 + 0.5
        assert (rgb_in < 0.97).any(axis=2).mean() > 0.5       # the noisy scene fills the input


def test_alpha_is_used_and_the_network_is_not_run():
    rgb, mask = photo()
    rgba = np.concatenate([rgb, (mask * 255).astype(np.uint8)[..., None]], axis=2)
    net = Net()
    for mode in ("auto", "true", "false"):
        f = frame_object(rgba, SPEC, net, mode)
        assert f.mask_source == "alpha" and f.box == (30, 120, 90, 170)
    assert net.calls == []


def test_foreground_ratio_sets_the_objects_share_of_the_square():
    rgb, mask = photo()
    for ratio in (0.5, 0.85, 1.0):
        rows, _ = extent(frame_object(rgb, SPEC, Net(), foreground_ratio=ratio).image)
        assert abs(rows - ratio * 64) <= 2
    with pytest.raises(ImageError, match="foreground_ratio"):
        frame_object(rgb, SPEC, Net(), foreground_ratio=0.01)


def test_no_object_and_bad_requests_are_clear_errors():
    empty, _ = photo(boxes=())
    with pytest.raises(NoObjectError, match="no object"):
        frame_object(empty, SPEC, Net())
    tiny, _ = photo(boxes=((5, 5, 7, 7),))             # 4 pixels of 24,000: below min_area
    with pytest.raises(NoObjectError, match="covers"):
        frame_object(tiny, SPEC, Net())
    transparent = np.zeros((20, 20, 4), np.uint8)
    with pytest.raises(NoObjectError, match="transparent"):
        frame_object(transparent, SPEC, Net())
    faint = np.full((20, 20, 4), 127, np.uint8)        # a ghost: no pixel even half opaque
    with pytest.raises(NoObjectError, match="peaks at 127 of 255"):
        frame_object(faint, SPEC, Net())


@pytest.mark.parametrize("height,width", [(2, 2), (7, 3), (1, 7), (8, 1), (5, 8), (30, 2)])
def test_an_object_cut_out_by_its_alpha_is_at_least_min_object_side_across(height, width):
    rgba = np.zeros((64, 48, 4), np.uint8)
    rgba[20:20 + height, 10:10 + width] = 255
    if max(height, width) < MIN_OBJECT_SIDE:
        with pytest.raises(NoObjectError, match=f"only {width}x{height} pixels"):
            frame_object(rgba, SPEC, Net())
    else:
        framed = frame_object(rgba, SPEC, Net())
        assert framed.mask_source == "alpha" and framed.box == (20, 10, 20 + height, 10 + width)
    rgb, _ = photo()
    with pytest.raises(ImageError, match="needs a foreground network"):
        frame_object(rgb, SPEC, None, "true")
    with pytest.raises(ImageError, match="auto, true, false"):
        frame_object(rgb, SPEC, Net(), "yes")


def test_specks_are_removed_and_do_not_widen_the_crop():
    specked, mask = photo(boxes=((30, 120, 90, 170), (2, 2, 5, 5)))   # 9 px against the object's 3,000
    assert frame_object(specked, SPEC, Net()).box == (30, 120, 90, 170)
    cleaned = clean_mask(Net()(specked), MaskSpec())
    assert cleaned[3, 3] == 0 and cleaned[30:90, 120:170].min() == 1
    two, _ = photo(boxes=((30, 120, 90, 170), (30, 10, 90, 60)))     # a second object as large: both kept
    assert frame_object(two, SPEC, Net()).box == (30, 10, 90, 170)


def test_an_object_touching_the_border_and_one_filling_the_photo():
    edge, _ = photo(boxes=((0, 150, 70, 200),))
    f = frame_object(edge, SPEC, Net())
    assert f.box == (0, 150, 70, 200) and np.isfinite(f.image).all()
    full, _ = photo(boxes=((0, 0, 120, 200),))
    net = Net()
    f = frame_object(full, SPEC, net)
    assert f.mask_source == "network" and f.box == (0, 0, 120, 200) and f.mask.min() == 255
    assert net.calls == [(120, 200)]                   # a large object: no second pass


def test_a_small_object_in_a_large_photo_is_segmented_again_at_full_resolution():
    rgb, mask = photo(h=800, w=1200, boxes=((560, 900, 680, 1080),))
    calls = []

    def coarse(img):                                   # a network that sees a 16 px grid only
        calls.append(img.shape[:2])
        small = resize_mask(Net()(img), 16, 16)
        return resize_mask(small, *img.shape[:2])

    f = frame_object(rgb, SPEC, coarse)
    assert calls[0] == (800, 1200) and 128 <= calls[1][0] == calls[1][1] < 300   # its square, not upsampled
    got, truth = f.mask > 127, mask > 0.5
    iou = (got & truth).sum() / (got | truth).sum()
    once = resize_mask(resize_mask(mask, 16, 16), 800, 1200) > 0.5
    assert iou > 0.85 > (once & truth).sum() / (once | truth).sum()


def test_a_small_square_is_looked_at_again_only_by_a_network_trained_for_it():
    rgb, _ = photo(h=400, w=600, boxes=((300, 450, 340, 510),))     # its square: 84 px a side
    for spec, looks in ((MaskSpec(size=128), 1), (MaskSpec(size=128, refine_min=32), 2),
                        (MaskSpec(size=128, refine_min=90), 1)):
        net = Net()
        mask = object_mask(rgb, net, spec)
        assert len(net.calls) == looks and mask_bounds(mask > 0.5) == (300, 450, 340, 510)
    assert net.calls[0] == (400, 600)
    net = Net()
    object_mask(rgb, net, MaskSpec(size=128, refine_min=32))
    assert net.calls[1] == (84, 84)


def test_a_second_look_must_find_an_object_of_the_whole_photos_minimum_area():
    """The second look's mask counts against the whole photo's area: a piece the closer look keeps,
    large in its square but under ``min_area`` of the photo, is no object, and the first look stands."""
    rgb, truth = photo(h=800, w=1200, boxes=((560, 900, 680, 1080),))          # 21,600 px: 2.25% of the photo
    looks = []

    def fragment(img):                                   # the second look sees a 20 x 20 px piece of it
        looks.append(img.shape[:2])
        if len(looks) == 1:
            return Net()(img)
        mask = np.zeros(img.shape[:2], np.float32)
        cy, cx = img.shape[0] // 2, img.shape[1] // 2
        mask[cy - 10:cy + 10, cx - 10:cx + 10] = 1      # 400 px: 0.04% of the photo, 0.6% of its square
        return mask

    spec = MaskSpec(min_area=0.002)
    mask = object_mask(rgb, fragment, spec)
    assert len(looks) == 2 and 400 > spec.min_area * (looks[1][0] * looks[1][1])
    assert np.array_equal(mask > 0.5, truth > 0.5)                             # the first look's mask


def test_the_object_square_is_centred_on_the_box_and_clipped_to_the_image():
    assert object_square((40, 60, 60, 100), 200, 300, 0.25) == (20, 80, 50, 110)
    assert object_square((40, 60, 60, 100), 200, 300, 0.0) == (30, 70, 60, 100)
    assert object_square((0, 250, 10, 300), 200, 300, 0.5) == (0, 55, 225, 300)


def test_mask_input_and_output_map_between_the_photo_and_the_network():
    spec = MaskSpec(size=32)
    rgb = np.zeros((50, 80, 3), np.uint8)
    rgb[:, 40:] = 255
    x = mask_input(rgb, spec)
    assert x.shape == (3, 32, 32) and x.dtype == np.float32
    assert x[0, :, :15].max() == pytest.approx(-2.0) and x[0, :, 17:].min() == pytest.approx(2.0)
    logits = np.full((32, 32), -20.0, np.float32)
    logits[:, 16:] = 20.0
    p = mask_output(logits)
    assert p.shape == (32, 32) and p[:, :16].max() < 1e-6 and p[:, 16:].min() > 1 - 1e-6
    # the network's grid brought to the photo: resized without a guided filter
    q = to_image(rgb, p, spec)
    assert q.shape == (50, 80) and q[:, :38].max() < 0.01 and q[:, 42:].min() > 0.99
    assert resize_mask(np.ones((10, 10)), 3, 4).shape == (3, 4)


def test_when_the_second_look_finds_nothing_the_first_stands():
    rgb, mask = photo(h=800, w=1200, boxes=((560, 900, 680, 1080),))
    calls = []

    def forgetful(img):                                # finds the object in the photo, not in its square
        calls.append(img.shape[:2])
        return Net()(img) if len(calls) == 1 else np.zeros(img.shape[:2], np.float32)

    f = frame_object(rgb, SPEC, forgetful)
    assert len(calls) == 2 and f.box == (560, 900, 680, 1080)


def test_clean_mask_is_its_whole_image_definition():
    """On random soft masks, alone and placed in a larger image: the mask itself when every
    component is kept, else the mask where a pixel is within 2 pixels (4-connected steps) of a kept
    component and 0 elsewhere; NoObjectError when too little is kept; ``area`` sets what the kept
    share is of."""

    rng = np.random.default_rng(0)
    spec = MaskSpec()
    checked = 0
    for _ in range(200):
        h, w = (int(v) for v in rng.integers(20, 160, 2))
        soft = ndimage.gaussian_filter(rng.random((h, w)).astype(np.float32), rng.uniform(0.5, 4))
        soft = np.clip((soft - soft.mean()) * rng.uniform(5, 40) + 0.3, 0, 1).astype(np.float32)
        labels, n = ndimage.label(soft > 0.5)
        sizes = np.bincount(labels.ravel(), minlength=n + 1)[1:]
        keep = np.flatnonzero(sizes >= spec.keep * sizes.max()) + 1 if n else np.array([], int)
        if n == 0 or sizes[keep - 1].sum() < spec.min_area * soft.size:
            with pytest.raises(NoObjectError):
                clean_mask(soft, spec)
            continue
        near = ndimage.binary_dilation(np.isin(labels, keep), iterations=2)
        want = soft if len(keep) == n else np.where(near, soft, 0)
        assert np.array_equal(clean_mask(soft, spec), want), (h, w)
        # the same mask inside a larger image, anywhere (its edges included): the same result there
        canvas, placed = np.zeros((h + 60, w + 60), np.float32), np.zeros((h + 60, w + 60), np.float32)
        y, x = (int(v) for v in rng.integers(0, 61, 2))
        canvas[y:y + h, x:x + w], placed[y:y + h, x:x + w] = soft, want
        assert np.array_equal(clean_mask(canvas, spec, area=soft.size), placed), (h, w, y, x)
        checked += 1
    assert checked > 100
    dot = np.zeros((10, 10), np.float32)
    dot[4:6, 4:6] = 1                                           # 4 pixels: 4% of its own 100, 0.1% of 4,000
    assert clean_mask(dot, spec)[4, 4] == 1
    with pytest.raises(NoObjectError, match="0.10% of it"):
        clean_mask(dot, spec, area=4000)


def test_the_guided_filter_follows_the_images_edges():
    """A mask blurred as a low-resolution network blurs it (a thin bar bloated, a square's corners
    rounded) comes back close to the objects the image shows; flat and linear inputs stay as they
    are."""

    from model.image.mask import guided_filter

    rgb = np.full((60, 80, 3), 220, np.uint8)
    truth = np.zeros((60, 80), bool)
    for sl in (np.s_[28:31, 10:70], np.s_[5:20, 5:20]):           # a 3-pixel bar and a square
        rgb[sl], truth[sl] = 30, True
    smear = np.clip(ndimage.gaussian_filter(truth.astype(np.float32), 3) * 2.2, 0, 1)

    def iou(m):
        return (m & truth).sum() / (m | truth).sum()

    q = guided_filter(rgb, smear, 4, 1e-4)
    assert q.dtype == np.float32 and 0 <= q.min() and q.max() <= 1
    assert iou(smear > 0.5) < 0.6 and iou(q > 0.5) > 0.9
    flat = np.full((60, 80), 0.3, np.float32)
    assert np.allclose(guided_filter(rgb, flat, 4, 1e-4), 0.3, atol=1e-5)
    grey = (rgb.mean(axis=2) / 255).astype(np.float32)
    assert np.allclose(guided_filter(rgb, grey, 4, 1e-6), grey, atol=1e-3)


def test_object_mask_applies_the_guided_filter_to_each_look():
    """A network that sees the objects blurred: with the spec's guide the mask is far closer to them."""

    rgb, truth = photo(120, 200, ((30, 120, 90, 170), (40, 20, 44, 100)))     # a block and a thin bar

    def blurry(img):
        return np.clip(ndimage.gaussian_filter(Net()(img), 3) * 2.2, 0, 1)

    def iou(spec):
        m = object_mask(rgb, blurry, spec) > 0.5
        return float((m & (truth > 0)).sum() / (m | (truth > 0)).sum())

    plain, guided = iou(MaskSpec(refine=0)), iou(MaskSpec(refine=0, guide=2.5, guide_eps=1e-4))
    assert guided > 0.9 and guided > plain + 0.05
    assert MaskSpec.from_dict({"size": 128}).guide == 0.0       # bundles without it: no filter


def test_a_network_that_answers_on_its_grid_is_brought_to_the_photo():
    """A stand-in network answering on a 128² grid over the photo, as the real one does: the mask
    comes back at the photo's size, on the object, with and without the guided filter; a small
    object in a large photo gets its second look on its own square."""
    rgb, truth = photo()

    def on_grid(img):
        return resize_mask(Net()(img), 128, 128)

    for spec in (MaskSpec(refine=0), MaskSpec(refine=0, guide=2, guide_eps=3e-5)):
        mask = object_mask(rgb, on_grid, spec)
        assert mask.shape == rgb.shape[:2] and mask.dtype == np.float32 and 0 <= mask.min() and mask.max() <= 1
        hard = mask > 0.5
        assert (hard & (truth > 0)).sum() / (hard | (truth > 0)).sum() > 0.97, spec
    big, small_truth = photo(h=800, w=1200, boxes=((560, 900, 680, 1080),))
    looks = []

    def counted(img):
        looks.append(img.shape[:2])
        return on_grid(img)

    f = frame_object(big, SPEC, counted, mask_spec=MaskSpec(guide=2, guide_eps=3e-5))
    assert looks[0] == (800, 1200) and len(looks) == 2 and looks[1][0] == looks[1][1] < 400
    assert f.box == (560, 900, 680, 1080) and np.array_equal(f.mask > 127, small_truth > 0.5)


def test_the_guided_filter_brings_a_coarse_grid_to_the_image_along_its_edges():
    """A mask on a coarse grid over a large image (as the network's 128² covers a photo): the guided
    filter's output at the image's resolution follows the objects' edges, far closer to them than
    the grid resized; and a grid the image's own size is the plain guided filter."""

    from model.image.mask import guided_filter

    rng = np.random.default_rng(0)
    rgb = np.full((600, 800, 3), 200, np.uint8)
    truth = np.zeros((600, 800), bool)
    for k in range(6):                                          # dark bars 4-11 px thin: under a grid pixel
        y, x = rng.integers(0, 450), rng.integers(0, 650)
        thin, long = rng.integers(4, 12), rng.integers(60, 150)
        hh, ww = (thin, long) if k % 2 else (long, thin)
        rgb[y:y + hh, x:x + ww], truth[y:y + hh, x:x + ww] = 40, True
    rgb = np.clip(rgb + rng.normal(0, 6, rgb.shape), 0, 255).astype(np.uint8)
    grid = resize_mask(truth.astype(np.float32), 64, 64)       # a perfect mask, at 64²

    def iou(m):
        return (m & truth).sum() / (m | truth).sum()

    out = guided_filter(rgb, grid, 1, 1e-4)
    assert out.shape == (600, 800) and out.dtype == np.float32 and 0 <= out.min() and out.max() <= 1
    assert iou(resize_mask(grid, 600, 800) > 0.5) < 0.7 and iou(out > 0.5) > 0.95
    # the image's own grid: each output pixel is the windows' mean fit, computed here directly
    small, p = rgb[:40, :50], np.clip(ndimage.gaussian_filter(truth[:40, :50].astype(np.float32), 2) * 2, 0, 1)
    g = np.asarray(Image.fromarray(small).convert("L"), np.float64) / 255

    def box(x):
        return ndimage.uniform_filter(x, 5, mode="reflect")

    a = (box(g * p) - box(g) * box(p)) / (box(g * g) - box(g) ** 2 + 1e-4)
    want = np.clip(box(a) * g + box(box(p) - a * box(g)), 0, 1)
    assert np.abs(guided_filter(small, p, 2, 1e-4) - want).max() < 1e-4


def test_cross_dilation_is_scipys_binary_dilation():
    """Shifted ORs give ``ndimage.binary_dilation`` (4-neighbour cross, iterated, nothing beyond the
    border) on random masks, pixels on the border included."""
    rng = np.random.default_rng(3)
    for _ in range(50):
        mask = rng.random(tuple(int(v) for v in rng.integers(1, 40, 2))) < rng.uniform(0.01, 0.3)
        for times in (1, 2, 3):
            assert np.array_equal(cross_dilation(mask, times), ndimage.binary_dilation(mask, iterations=times))


def test_the_blend_of_the_guided_filter_is_pillows_bilinear_resizing_bit_for_bit():
    """``bilinear_blend`` against ``clip(resize(a) guide + resize(b), 0, 1)`` with Pillow's resizing
    (``resize_mask``), bit for bit: enlarged both ways, and enlarged one way while reduced the
    other (Pillow widens the triangle where it reduces)."""
    rng = np.random.default_rng(4)
    for _ in range(80):
        h, w = (int(v) for v in rng.integers(3, 130, 2))
        H = int(rng.integers(h, 600)) if rng.random() < 0.8 else int(rng.integers(1, h + 1))
        W = int(rng.integers(w, 600)) if H <= h or rng.random() < 0.8 else int(rng.integers(1, w + 1))
        a, b = rng.normal(0, 3, (h, w)).astype(np.float32), rng.normal(0.5, 1, (h, w)).astype(np.float32)
        guide = rng.random((H, W)).astype(np.float32)
        want = np.clip(resize_mask(a, H, W) * guide + resize_mask(b, H, W), 0.0, 1.0)
        got = bilinear_blend(a, b, guide)
        assert got.dtype == np.float32 and np.array_equal(got.view(np.uint32), want.view(np.uint32)), (h, w, H, W)


def test_a_window_of_the_blend_is_the_whole_blends_window_bit_for_bit():
    """``bilinear_blend`` on a window (y0, y1, x0, x1) against the whole blend's rows and columns:
    enlarged both ways, one way reduced (down first, or across first), a size unchanged."""
    rng = np.random.default_rng(6)
    for _ in range(60):
        h, w = (int(v) for v in rng.integers(3, 60, 2))
        H = int(rng.integers(h, 300)) if rng.random() < 0.7 else int(rng.integers(1, h + 1))
        W = int(rng.integers(w, 300)) if H <= h or rng.random() < 0.7 else int(rng.integers(1, w + 1))
        if rng.random() < 0.15:
            W = w
        a, b = rng.normal(0, 3, (h, w)).astype(np.float32), rng.normal(0.5, 1, (h, w)).astype(np.float32)
        guide = rng.random((H, W)).astype(np.float32)
        whole = bilinear_blend(a, b, guide)
        y0, x0 = int(rng.integers(0, H)), int(rng.integers(0, W))
        y1, x1 = int(rng.integers(y0 + 1, H + 1)), int(rng.integers(x0 + 1, W + 1))
        part = bilinear_blend(a, b, guide, (y0, y1, x0, x1))
        assert np.array_equal(part.view(np.uint32), whole[y0:y1, x0:x1].view(np.uint32)), (h, w, H, W)


def test_the_blend_keeps_pillows_skipped_pass_and_non_finite_values():
    """Where a size does not change Pillow makes no pass in that direction: an infinite or NaN
    coefficient stays in its own row or column, as in Pillow's output (a tap of weight 0 would
    spread NaN to its neighbours)."""
    rng = np.random.default_rng(5)
    for h, w, H, W in ((5, 4, 5, 9), (6, 7, 13, 7), (5, 4, 5, 4 * 40), (3, 9, 50, 9)):
        a, b = rng.normal(0, 1, (h, w)).astype(np.float32), rng.normal(0, 1, (h, w)).astype(np.float32)
        a[2, 1], b[1, 2] = np.inf, np.nan
        guide = rng.random((H, W)).astype(np.float32)
        with np.errstate(invalid="ignore"):
            want = np.clip(resize_mask(a, H, W) * guide + resize_mask(b, H, W), 0.0, 1.0)
        got = bilinear_blend(a, b, guide)
        assert np.array_equal(np.isnan(got), np.isnan(want)), (h, w, H, W)
        assert np.array_equal(got[~np.isnan(got)], want[~np.isnan(want)]), (h, w, H, W)
    with pytest.raises(ValueError, match="one shape"):
        bilinear_blend(np.zeros((4, 4), np.float32), np.zeros((4, 5), np.float32), np.zeros((8, 8), np.float32))


def colour_network(colour: tuple[int, int, int]):
    """A stand-in foreground network on the image's own pixels: the object is the given colour."""
    want = np.asarray(colour, np.int32)
    return lambda rgb: (np.abs(rgb[..., :3].astype(np.int32) - want).max(axis=2) < 30).astype(np.float32)


def test_a_box_is_judged_on_what_it_holds_not_on_its_context():
    """The network sees the box with some of the photo about it, but specks, sizes and the answer
    are the box's own: a small object boxed beside a larger one that reaches into the context is
    found; a box whose context alone holds the object, or whose object is under MIN_OBJECT_SIDE
    pixels, is refused with the box named."""
    rng = np.random.default_rng(0)
    rgb = rng.uniform(120, 255, (300, 300, 3)).astype(np.uint8)
    rgb[150:160, 150:160] = (20, 40, 160)                 # a 10 x 10 object, boxed below
    rgb[100:128, 100:200] = (20, 40, 160)                 # a 28 x 100 one ending 2 pixels above the box
    net = colour_network((20, 40, 160))
    # the box 50 x 50, its context 25 pixels: 23 x 95 pixels of the large object, over 10 times the small one
    f = frame_object(rgb, SPEC, net, "true", region=(130, 130, 180, 180))
    ours = f.mask > 127
    assert ours[150:160, 150:160].all() and ours.sum() == 100        # the small object, nothing else
    with pytest.raises(NoObjectError, match="the box holds no object"):
        frame_object(rgb, SPEC, net, "true", region=(160, 100, 200, 200))   # below both: the large one in its context
    rgb[200:205, 50:55] = (20, 40, 160)                   # 5 x 5: under MIN_OBJECT_SIDE
    with pytest.raises(NoObjectError, match="only 5x5 pixels"):
        frame_object(rgb, SPEC, net, "true", region=(195, 45, 210, 60))


def grid_network(size: int = 32, colour: tuple[int, int, int] = OBJECT):
    """A stand-in foreground network that answers on its own ``size``² grid over the whole image,
    as the real one does: the object's colour, box-filtered to the grid."""
    want = np.asarray(colour, np.int32)

    def segment(rgb: np.ndarray) -> np.ndarray:
        hit = (np.abs(rgb[..., :3].astype(np.int32) - want).max(axis=2) < 30).astype(np.float32)
        return resize_mask(hit, size, size)
    return segment


def test_the_first_looks_window_holds_every_value_above_one_half_bit_for_bit():
    """``first_look_window``: inside, the whole guided mask's values; outside, none above 0.5; and
    the blend of ``blend_coefficients`` is the whole mask."""
    spec = MaskSpec(size=32, guide=1.0, guide_eps=3e-5)
    rng = np.random.default_rng(7)
    windows = 0
    for _ in range(40):
        h, w = (int(v) for v in rng.integers(60, 400, 2))
        rgb = rng.integers(100, 256, (h, w, 3)).astype(np.uint8)
        t, l = int(rng.integers(0, h - 20)), int(rng.integers(0, w - 20))
        rgb[t:t + int(rng.integers(5, h // 3)), l:l + int(rng.integers(5, w // 3))] = OBJECT
        if rng.random() < 0.5:                         # a network's blur: a smooth bump, values all the way down
            gy, gx = np.mgrid[:32, :32]
            bump = np.exp(-np.hypot(gy - rng.uniform(5, 27), gx - rng.uniform(5, 27)) ** 2 / rng.uniform(4, 60))
            p = (bump * rng.uniform(0.55, 1.0)).astype(np.float32)
        else:
            p = grid_network(32)(rgb) * np.float32(rng.uniform(0.6, 1.0))
        guide = guide_of(rgb)
        whole = to_image(rgb, p, spec, guide)
        coefficients = blend_coefficients(p, spec, guide)
        assert np.array_equal(bilinear_blend(*coefficients, guide).view(np.uint32), whole.view(np.uint32))
        seen = first_look_window(*coefficients, guide)
        if seen is None:                               # nothing above 0.5, or a window too large to save work
            continue
        windows += 1
        values, (y0, y1, x0, x1) = seen
        assert np.array_equal(values.view(np.uint32), whole[y0:y1, x0:x1].view(np.uint32))
        outside = whole.copy()
        outside[y0:y1, x0:x1] = 0
        assert outside.max() <= 0.5 and (y1 - y0) * (x1 - x0) <= FIRST_LOOK_WINDOW * h * w
    assert windows >= 25


def test_a_mask_made_from_the_first_looks_window_is_the_whole_first_looks(monkeypatch):
    """object_mask with the window and with the first look made whole give the same mask: a small
    object (second look), two objects far apart, a speck, a second look that finds nothing (the
    whole first look then), a large object (no window)."""
    import model.image.mask as mask_module

    spec = MaskSpec(size=32, guide=1.0, guide_eps=3e-5, keep=0.2)
    cases = [photo(400, 600, ((300, 450, 360, 540),)), photo(400, 600, ((20, 20, 80, 90), (300, 450, 360, 540))),
             photo(400, 600, ((200, 200, 290, 330), (30, 500, 36, 506))), photo(300, 300, ((20, 20, 280, 270),))]
    net = grid_network(32)
    calls = []

    def forgetful(img):
        calls.append(img.shape[:2])
        return net(img) if len(calls) % 2 == 1 else np.zeros((32, 32), np.float32)

    windows = []
    real_window = mask_module.first_look_window

    def counted(*args):
        seen = real_window(*args)
        windows.append(seen is not None)
        return seen

    for rgb, _ in cases:
        for segment in (net, forgetful):
            calls.clear()
            with monkeypatch.context() as m:
                m.setattr(mask_module, "first_look_window", counted)
                got = object_mask(rgb, segment, spec)
            with monkeypatch.context() as m:
                m.setattr(mask_module, "first_look_window", lambda *a: None)
                calls.clear()
                want = object_mask(rgb, segment, spec)
            assert np.array_equal(got.view(np.uint32), want.view(np.uint32))
    assert sum(windows) >= 4                  # the window path ran (both small-object photos, each network)


def test_mask_confidence_bands_the_edge_as_scipys_window_filters_do():
    rng = np.random.default_rng(3)
    for _ in range(30):
        h, w = (int(v) for v in rng.integers(20, 300, 2))
        yy, xx = np.mgrid[:h, :w]
        mask = np.clip(1.5 - np.hypot(yy - h * rng.random(), xx - w * rng.random()) / (0.3 * max(h, w)), 0, 1)
        mask = (mask * rng.uniform(0.8, 1.0, mask.shape)).astype(np.float32)
        hard = mask > 0.5
        if not hard.any():
            continue
        box = mask_bounds(hard)
        reach = max(2, round(0.01 * max(box[2] - box[0], box[3] - box[1])))
        top, left = max(0, box[0] - reach - 1), max(0, box[1] - reach - 1)
        near = hard[top:box[2] + reach + 1, left:box[3] + reach + 1]
        p = mask[top:box[2] + reach + 1, left:box[3] + reach + 1]
        band = ((ndimage.maximum_filter(near.view(np.uint8), 2 * reach + 1) > 0)
                & (ndimage.minimum_filter(near.view(np.uint8), 2 * reach + 1, mode="constant", cval=0) == 0))
        want = float(np.abs(2 * p[band] - 1).mean()) if band.any() else 1.0
        assert mask_confidence(mask) == want
