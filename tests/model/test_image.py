"""The shared image preprocessing: every kind of image Pillow reads, the crop, and clear errors."""

import io

import numpy as np
import pytest
from PIL import Image

from model.image.decode import ImageError, decode_image
from model.image.frame import ImageSpec, _edge_padded, load_and_prepare, object_box, prepare_image

SPEC = ImageSpec(size=32)


def encode(img: Image.Image, fmt: str = "PNG", **kw) -> bytes:
    buf = io.BytesIO()
    img.save(buf, fmt, **kw)
    return buf.getvalue()


def scene(h=60, w=90, box=(10, 20, 40, 50), colour=(200, 30, 30), alpha=True) -> np.ndarray:
    """A red rectangle on transparent (or white) ground."""
    a = np.zeros((h, w, 4), np.uint8)
    a[..., :3] = 255
    a[..., 3] = 0 if alpha else 255
    t, l, b, r = box
    a[t:b, l:r, :3] = colour
    a[t:b, l:r, 3] = 255
    return a


def test_crop_to_the_object_pads_to_square_and_normalises():
    x = prepare_image(scene(), SPEC)
    assert x.shape == (3, 32, 32) and x.dtype == np.float32
    red = x[0] * SPEC.std[0] + SPEC.mean[0]
    # the object is 30 x 30: it fills the square but the margin (5% per side) stays background
    assert red[16, 16] == pytest.approx(200 / 255, abs=0.02)
    assert red[0, 0] == pytest.approx(1.0, abs=0.02)
    inside = (x[1] * SPEC.std[1] + SPEC.mean[1]) < 0.5        # green low = the red object
    rows = np.flatnonzero(inside.any(1))
    assert 0 < rows[0] <= 3 and 28 <= rows[-1] < 31


def test_the_same_object_gives_the_same_tensor_wherever_it_sits_and_whatever_the_ground():
    a = prepare_image(scene(box=(10, 20, 40, 50)), SPEC)
    b = prepare_image(scene(h=120, w=80, box=(70, 5, 100, 35)), SPEC)
    c = prepare_image(scene(alpha=False), SPEC)                # opaque: cropped by the border colour
    assert np.abs(a - b).max() < 1e-5
    assert np.abs(a - c).max() < 1e-5


@pytest.mark.parametrize("mode", ["RGB", "RGBA", "L", "LA", "P", "CMYK", "I;16", "I", "F", "1"])
def test_every_pillow_mode_decodes_to_rgba(mode):
    rgb = Image.fromarray(scene(alpha=False)[..., :3])
    if mode == "I;16":
        img = Image.fromarray(np.asarray(rgb.convert("L"), np.uint16) * 257)
    else:
        img = rgb.convert(mode)
    fmt = "TIFF" if mode in ("CMYK", "I", "F", "I;16") else "PNG"
    rgba = decode_image(encode(img, fmt))
    assert rgba.shape == (60, 90, 4) and rgba.dtype == np.uint8
    assert object_box(rgba) == (10, 20, 40, 50)
    assert prepare_image(rgba, SPEC).shape == (3, 32, 32)


def test_sixteen_bit_png_is_scaled_not_clipped():
    g = np.full((8, 8), 40000, np.uint16)
    rgba = decode_image(encode(Image.fromarray(g)))
    assert abs(int(rgba[0, 0, 0]) - round(40000 / 65535 * 255)) <= 1


@pytest.mark.parametrize("peak,top", [(200, 255), (40000, 65535), (200000, 200000)])
def test_32_bit_integer_pixels_are_scaled_by_the_bits_they_use(peak, top):
    """8-bit values stay, 16-bit ones are scaled by 65535, wider ones by their peak: never clipped."""
    g = np.zeros((8, 8), np.int32)
    g[2:6, 2:6] = peak
    g[6:, :] = peak // 2
    rgba = decode_image(encode(Image.fromarray(g), "TIFF"))
    assert rgba[0, 0, 0] == 0
    for y, value in ((3, peak), (7, peak // 2)):
        assert abs(int(rgba[y, 3, 0]) - value / top * 255) <= 0.5


def test_palette_transparency_jpeg_webp_and_gif_first_frame():
    p = Image.fromarray(scene()).convert("RGBA").quantize(8)
    frames = [Image.fromarray(scene(box=(0, 0, 10, 10), alpha=False)[..., :3]),
              Image.fromarray(scene(alpha=False)[..., :3])]
    gif = io.BytesIO()
    frames[0].save(gif, "GIF", save_all=True, append_images=frames[1:])
    for data in (encode(p), encode(Image.fromarray(scene(alpha=False)[..., :3]), "JPEG", quality=95),
                 encode(Image.fromarray(scene()), "WEBP", lossless=True)):
        box = object_box(decode_image(data))
        assert box is not None and abs(box[0] - 10) <= 1 and abs(box[3] - 50) <= 1
    assert object_box(decode_image(gif.getvalue())) == (0, 0, 10, 10)


def test_exif_rotation_is_applied():
    img = Image.fromarray(scene(alpha=False)[..., :3])           # 60 x 90, landscape
    exif = Image.Exif()
    exif[0x0112] = 6                                             # rotate 90 degrees clockwise to view
    rgba = decode_image(encode(img, "JPEG", exif=exif.tobytes()))
    assert rgba.shape[:2] == (90, 60)


def test_tiny_flat_and_transparent_images():
    one = decode_image(encode(Image.new("RGB", (1, 1), (10, 200, 10))))
    assert prepare_image(one, SPEC).shape == (3, 32, 32)              # a 1x1 image: the whole image
    flat = np.full((20, 30, 3), 128, np.uint8)
    assert object_box(np.dstack([flat, np.full((20, 30), 255, np.uint8)])) is None
    assert prepare_image(flat, SPEC).shape == (3, 32, 32)             # nothing stands out: whole image
    with pytest.raises(ImageError, match="fully transparent"):
        prepare_image(np.zeros((10, 10, 4), np.uint8), SPEC)


def test_not_an_image_truncated_and_bombs_are_clear_errors(tmp_path):
    with pytest.raises(ImageError, match="not an image"):
        decode_image(b"")
    with pytest.raises(ImageError, match="not an image"):
        decode_image(b"ply\nformat ascii 1.0\n")
    data = encode(Image.fromarray(scene()[..., :3]), "PNG")
    with pytest.raises(ImageError, match="truncated or corrupt"):
        decode_image(data[: len(data) // 2])
    big = encode(Image.new("L", (5000, 5000)), "PNG")                 # 25 MP, compresses to ~25 kB
    with pytest.raises(ImageError, match="more than the limit"):
        decode_image(big, max_pixels=10_000_000)
    with pytest.raises(ImageError, match="cannot read"):
        decode_image(tmp_path / "missing.png")
    with pytest.raises(ImageError, match="expected an"):
        prepare_image(np.zeros((4, 4), np.uint8), SPEC)
    ok = tmp_path / "ok.png"
    ok.write_bytes(data)
    assert load_and_prepare(ok, SPEC).shape == (3, 32, 32)


def test_composite_is_the_rounded_blend_for_every_colour_alpha_and_background():
    """The integer blend equals round(c a + b (1 - a)), a = alpha / 255, for all 256^3 triples."""
    from model.image.frame import composite

    c, a = np.meshgrid(np.arange(256), np.arange(256), indexing="ij")     # colour x alpha
    rgba = np.dstack([c, c, c, a]).astype(np.uint8)
    for b in range(256):
        want = np.round(c * (a / 255.0) + b * (1 - a / 255.0))
        got = composite(rgba, (b, b, b))
        assert got.dtype == np.uint8 and got.shape == (256, 256, 3)
        assert np.array_equal(got, np.repeat(want[..., None], 3, axis=2)), b
    # per channel: each channel blends with its own background value
    assert composite(np.array([[[10, 20, 30, 0]]], np.uint8), (1, 2, 3)).tolist() == [[[1, 2, 3]]]


def _encode(img: Image.Image, fmt: str, **kw) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format=fmt, **kw)
    return buf.getvalue()


def test_decode_photo_reduces_a_large_photo_to_the_working_size_and_keeps_its_upload_size():
    from model.image.decode import decode_photo

    rng = np.random.default_rng(0)
    small = rng.integers(0, 256, (30, 40, 3), dtype=np.uint8)
    big = Image.fromarray(small).resize((2000, 1500), Image.Resampling.NEAREST)        # 4:3, short side 1500
    for fmt in ("JPEG", "PNG"):
        d = decode_photo(_encode(big, fmt, **({"quality": 95} if fmt == "JPEG" else {})), work_side=600)
        assert d.size == (1500, 2000) and d.rgba.shape == (600, 800, 4) and d.rgba.dtype == np.uint8
        back = np.asarray(Image.fromarray(d.rgba[..., :3]).resize((40, 30), Image.Resampling.BOX), np.float32)
        assert np.abs(back - small).mean() < 6                  # the same picture, only smaller
    full = decode_photo(_encode(big, "PNG"), work_side=None)
    assert full.rgba.shape == (1500, 2000, 4) and full.size == (1500, 2000)
    little = _encode(Image.fromarray(small), "PNG")             # already below the working size: untouched
    assert np.array_equal(decode_photo(little, work_side=600).rgba, decode_image(little))


def test_decode_photo_size_follows_the_exif_rotation():
    from model.image.decode import decode_photo

    img = Image.fromarray(np.zeros((1200, 1800, 3), np.uint8))
    exif = Image.Exif()
    exif[0x0112] = 6                                           # rotated a quarter: the sides swap
    d = decode_photo(_encode(img, "JPEG", exif=exif), work_side=600)
    assert d.size == (1800, 1200) and d.rgba.shape[:2] == (900, 600)


def test_reducing_a_transparent_image_does_not_bleed_the_hidden_colour():
    from model.image.decode import decode_photo

    rgba = np.zeros((1000, 1000, 4), np.uint8)
    rgba[..., 0] = 255                                          # hidden red under full transparency
    rgba[:, 505:] = (0, 0, 255, 255)                            # an opaque blue right half
    d = decode_photo(_encode(Image.fromarray(rgba, "RGBA"), "PNG"), work_side=100)
    edge = d.rgba[:, 50]                                        # half transparent, half blue
    assert d.rgba.shape == (100, 100, 4) and 100 < edge[0, 3] < 160
    assert edge[0, 0] <= 2 and edge[0, 2] >= 250                # blue, not purple


def test_upload_box_and_mask_scale_back_to_the_uploaded_image():
    from model.image.frame import Framed, upload_box, upload_mask

    mask = np.zeros((100, 150), np.uint8)
    mask[20:40, 30:61] = 255
    framed = Framed(np.zeros((3, 8, 8), np.float32), "network", (20, 30, 40, 61), mask, (100, 150), (300, 450))
    assert upload_box(framed) == (60, 90, 120, 183)
    big = upload_mask(framed)
    assert big.shape == (300, 450) and big[61:119, 91:182].min() == 255 and big[:55].max() == 0
    same = Framed(framed.image, "network", framed.box, mask, (100, 150))
    assert upload_box(same) == same.box and upload_mask(same) is mask


def test_heic_and_avif_photos_decode_to_the_picture_saved():
    """HEIC (through pillow-heif) and AVIF (Pillow's own) decode to the picture that was saved."""
    rng = np.random.default_rng(0)
    small = rng.integers(0, 256, (12, 16, 3), dtype=np.uint8)
    img = Image.fromarray(small).resize((160, 120), Image.Resampling.NEAREST)
    for fmt in ("HEIF", "AVIF"):
        got = decode_image(_encode(img, fmt, quality=90))
        assert got.shape == (120, 160, 4) and got[..., 3].min() == 255
        back = np.asarray(Image.fromarray(got[..., :3]).resize((16, 12), Image.Resampling.BOX), np.float32)
        assert np.abs(back - small).mean() < 12, fmt


def _float_box(rgba: np.ndarray, tolerance: float) -> tuple[int, int, int, int] | None:
    """The border-colour box as NumPy computes it in float32 (object_box's formulation before its kernel)."""
    rgb = rgba[..., :3]
    ref = np.median(np.concatenate([rgb[0], rgb[-1], rgb[:, 0], rgb[:, -1]]), axis=0).astype(np.float32)
    mask = np.zeros(rgb.shape[:2], bool)
    for c in range(3):
        mask |= np.abs(rgb[..., c] - ref[c]) > tolerance
    rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    return None if not len(rows) else (int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1)


def test_the_border_colour_box_is_the_float_formulations_to_the_pixel():
    rng = np.random.default_rng(0)
    for i in range(400):
        h, w = (int(v) for v in rng.integers(1, 40, 2))
        base = rng.integers(0, 256, 3)
        changed = rng.random((h, w, 1)) < rng.choice([0.0, 0.05, 0.5])
        rgb = np.clip(base + rng.integers(-30, 31, (h, w, 3)) * changed, 0, 255).astype(np.uint8)
        rgba = np.dstack([rgb, np.full((h, w), 255, np.uint8)])
        tolerance = (0, 1, 24, 30, 255, 23.7, 12.5)[i % 7]
        assert object_box(rgba, tolerance) == _float_box(rgba, tolerance)


@pytest.mark.parametrize("layout", ["rgba", "rgba strided", "rgba crop", "rgb"])
def test_edge_padding_is_np_pad(layout):
    rng = np.random.default_rng(1)
    for _ in range(50):
        h, w = (int(v) for v in rng.integers(1, 30, 2))
        image = rng.integers(0, 256, (h + 4, w + 4, 4), dtype=np.uint8)
        image = {"rgba": image[:h, :w].copy(), "rgba strided": image[:h, ::-1][:, :w],
                 "rgba crop": image[2:h + 2, 1:w + 1], "rgb": np.ascontiguousarray(image[:h, :w, :3])}[layout]
        rows, cols = tuple(int(v) for v in rng.integers(0, 9, 2)), tuple(int(v) for v in rng.integers(0, 9, 2))
        padded = np.asarray(_edge_padded(image, rows, cols))
        assert np.array_equal(padded, np.pad(image[..., :3], (rows, cols, (0, 0)), mode="edge"))
