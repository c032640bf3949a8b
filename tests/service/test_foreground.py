"""Photos in the wild: /v1/image-to-shape finds the object (the image's alpha, or the bundle's
foreground network on an opaque photo), frames it at the asked foreground_ratio, says how in
X-Mask / X-Crop-Box / X-Foreground-Ratio, and answers debug=mask with the mask it used.

The network's mask is made deterministic by patching ``Runtime.segment`` (an oracle that returns
the object drawn); one test runs the real foreground graph of ``foreground_models_dir``."""

from __future__ import annotations

import io
import json
import shutil
import subprocess
import sys
import time
from typing import get_args

import numpy as np
import pytest
from PIL import Image, ImageDraw

from export.bundle import load_bundle
from export.runtime import Runtime
from model.image.frame import REMOVE_BACKGROUND
from model.image.mask import to_image
from service.metrics import Metrics, StageTimer
from service.schemas import RemoveBackground

from .conftest import make_client
from .test_api import REPO, png
from .test_bad_input import _err

OBJECT = (30, 40, 60)


@pytest.fixture(scope="module")
def fg_client(foreground_models_dir):
    with make_client(foreground_models_dir) as c:
        yield c


def scene(h: int = 160, w: int = 200, box: tuple[int, int, int, int] = (40, 90, 110, 170),
          seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """An opaque photo, a dark pentagon spanning ``box`` (top, left, bottom, right, exclusive) on a
    noisy bright gradient, and the pentagon's true mask (bool)."""
    rng = np.random.default_rng(seed)
    img = (150 + np.linspace(0, 60, w)[None, :, None] + rng.integers(0, 40, (h, w, 3))).astype(np.uint8)
    top, left, bottom, right = box
    third, quarter = top + (bottom - top) // 3, (right - left) // 4
    outline = Image.new("L", (w, h))
    ImageDraw.Draw(outline).polygon([(left, third), ((left + right) // 2, top), (right - 1, third),
                                     (right - 1 - quarter, bottom - 1), (left + quarter, bottom - 1)], fill=255)
    mask = np.asarray(outline) > 0
    img[mask] = np.asarray(OBJECT) + rng.integers(0, 10, (int(mask.sum()), 3))
    return img, mask


def true_box(mask: np.ndarray) -> tuple[int, int, int, int]:
    rows, cols = np.flatnonzero(mask.any(1)), np.flatnonzero(mask.any(0))
    return int(rows[0]), int(cols[0]), int(rows[-1]) + 1, int(cols[-1]) + 1


def oracle(rgb: np.ndarray) -> np.ndarray:
    """The drawn object's mask, read off the colours (the object is dark, the background bright) of
    an (H, W, 3|4) image."""
    return (rgb[..., :3].astype(np.int32).sum(axis=2) < 300).astype(np.float32)


@pytest.fixture
def segment_calls(monkeypatch) -> list[np.ndarray]:
    """``Runtime.segment`` patched to the oracle; the images it was called with."""
    calls = []

    def fake(self, rgb):
        calls.append(rgb)
        return oracle(rgb)

    monkeypatch.setattr(Runtime, "segment", fake)
    return calls


@pytest.fixture
def encoder_inputs(monkeypatch) -> list[np.ndarray]:
    """``Runtime.encode_image`` spied on: the encoder inputs it was given (it still runs)."""
    seen, real = [], Runtime.encode_image

    def spy(self, images):
        seen.append(np.array(images))
        return real(self, images)

    monkeypatch.setattr(Runtime, "encode_image", spy)
    return seen


def post(client, image: bytes, **params):
    return client.post("/v1/image-to-shape", params=params, files={"image": ("p.png", image, "image/png")})


def stages(r) -> set[str]:
    return {t.split(";")[0] for t in r.headers["server-timing"].split(", ")}


def crop_box(r) -> tuple[int, ...]:
    """X-Crop-Box (left, top, right, bottom) as (top, left, bottom, right), the order of true_box."""
    left, top, right, bottom = (int(v) for v in r.headers["x-crop-box"].split(","))
    return top, left, bottom, right


def test_the_schema_s_choices_are_the_preprocessing_s():
    assert get_args(RemoveBackground) == REMOVE_BACKGROUND


def test_a_stage_inside_another_is_not_counted_in_it():
    timer = StageTimer(Metrics())
    with timer("decode_input"):
        time.sleep(0.01)
        with timer("mask"):
            time.sleep(0.2)
    assert timer.seconds["mask"] >= 0.2 and 0.01 <= timer.seconds["decode_input"] < 0.15, timer.seconds


def test_a_transparent_png_uses_its_alpha_and_never_runs_the_network(fg_client, segment_calls):
    img, mask = scene()
    rgba = np.dstack([img, np.where(mask, 255, 0).astype(np.uint8)])
    r = post(fg_client, png(rgba))
    assert r.status_code == 200, r.text
    assert r.headers["x-mask"] == "alpha" and crop_box(r) == true_box(mask)
    assert segment_calls == [] and "mask" not in stages(r) and "decode_input" in stages(r)


def test_an_opaque_photo_is_cut_out_by_the_network(fg_client, segment_calls):
    img, mask = scene()
    r = post(fg_client, png(img))
    assert r.status_code == 200, r.text
    assert r.headers["x-mask"] == "network" and r.headers["x-foreground-ratio"] == "0.900"
    assert np.abs(np.subtract(crop_box(r), true_box(mask))).max() <= 1
    # the whole photo, then the object's square (its 80 px box grown 20% a side) at full resolution
    assert [c.shape for c in segment_calls] == [(160, 200, 4), (112, 112, 4)]      # RGBA, as decoded
    assert {"decode_input", "mask", "encoder", "decoder"} <= stages(r)


def test_remove_background_false_keeps_the_background(fg_client, segment_calls):
    img, _ = scene()
    r = post(fg_client, png(img), remove_background="false")
    assert r.status_code == 200, r.text
    assert r.headers["x-mask"] == "none" and segment_calls == [] and "mask" not in stages(r)


def test_a_photo_without_an_object_is_a_422(fg_client, monkeypatch):
    monkeypatch.setattr(Runtime, "segment", lambda self, rgb: np.zeros(rgb.shape[:2], np.float32))
    img, _ = scene()
    assert "no object found" in _err(post(fg_client, png(img)), 422, "no_object")["message"]
    blank = png(np.zeros((20, 30, 4), np.uint8))
    assert "fully transparent" in _err(post(fg_client, blank), 422, "no_object")["message"]


def test_without_a_foreground_network(client):
    img, mask = scene()
    r = post(client, png(img))                                     # auto: no mask, as before the network
    assert r.status_code == 200 and r.headers["x-mask"] == "none" and "mask" not in stages(r)
    body = _err(post(client, png(img), remove_background="true"), 422, "no_foreground_network")
    assert body["message"].startswith("remove_background=true needs a foreground network")
    rgba = np.dstack([img, np.where(mask, 255, 0).astype(np.uint8)])
    assert post(client, png(rgba), remove_background="true").headers["x-mask"] == "alpha"


def test_bad_remove_background_and_foreground_ratio_are_422(client):
    img, _ = scene()
    message = _err(post(client, png(img), remove_background="bogus"), 422, "invalid_request")["message"]
    assert "remove_background" in message and all(f"'{v}'" in message for v in ("auto", "true", "false"))
    for ratio in (0.2, 1.5):
        assert "foreground_ratio" in _err(post(client, png(img), foreground_ratio=ratio), 422, "invalid_request")["message"]
    assert "debug" in _err(post(client, png(img), debug="octree"), 422, "invalid_request")["message"]


def _extent(x: np.ndarray) -> float:
    """The object's longest side in an encoder input (3, S, S), as a share of S: the dark pixels
    (the object) on the white background the cut-out is composited on."""
    dark = x.mean(axis=0) < 0.0
    rows, cols = np.flatnonzero(dark.any(1)), np.flatnonzero(dark.any(0))
    return max(rows[-1] - rows[0] + 1, cols[-1] - cols[0] + 1) / x.shape[-1]


def test_foreground_ratio_is_the_object_s_share_of_the_encoder_input(fg_client, segment_calls, encoder_inputs):
    img, _ = scene()
    extents = {}
    for ratio in (0.6, 0.95):
        r = post(fg_client, png(img), foreground_ratio=ratio)
        assert r.status_code == 200, r.text
        assert r.headers["x-foreground-ratio"] == f"{ratio:.3f}" and r.headers["x-mask"] == "network"
        (x,) = encoder_inputs.pop()
        extents[ratio] = _extent(x)
    assert abs(extents[0.6] - 0.6) < 0.05 and abs(extents[0.95] - 0.95) < 0.05, extents


def test_debug_mask_is_the_mask_used_and_skips_the_model(fg_client, segment_calls, encoder_inputs):
    img, _ = scene()
    r = post(fg_client, png(img), debug="mask")
    assert r.status_code == 200, r.text
    assert r.headers["content-type"] == "image/png" and r.headers["x-mask"] == "network"
    got = Image.open(io.BytesIO(r.content))
    assert got.mode == "L" and got.size == (200, 160)
    want = oracle(img) * 255
    assert np.abs(np.asarray(got, np.float32) - want).max() <= 1 and (want > 0).sum() > 1000
    assert crop_box(r) == true_box(oracle(img) > 0) and "mask" in stages(r)
    assert encoder_inputs == [] and "encoder" not in stages(r)


def test_debug_mask_of_an_alpha_image_is_its_alpha(client):
    img, mask = scene()
    alpha = np.where(mask, 255, 0).astype(np.uint8)
    alpha[0, 0] = 77
    r = post(client, png(np.dstack([img, alpha])), debug="mask")
    assert r.status_code == 200 and r.headers["x-mask"] == "alpha"
    assert np.array_equal(np.asarray(Image.open(io.BytesIO(r.content))), alpha)


def test_debug_mask_without_a_mask_is_a_422(client, fg_client):
    img, _ = scene()
    assert "no foreground network" in _err(post(client, png(img), debug="mask"), 422, "no_mask")["message"]
    body = _err(post(fg_client, png(img), debug="mask", remove_background="false"), 422, "no_mask")
    assert "remove_background=false" in body["message"]


@pytest.mark.parametrize("h, w, box", [(200, 120, (60, 20, 150, 100)),      # portrait
                                       (120, 200, (20, 60, 100, 180)),      # landscape
                                       (150, 150, (0, 0, 70, 90)),          # at the top-left corner
                                       (150, 150, (50, 80, 150, 150))])     # at the bottom-right corner
def test_shapes_of_photos_and_objects_at_the_border(fg_client, segment_calls, h, w, box):
    img, mask = scene(h, w, box)
    r = post(fg_client, png(img))
    assert r.status_code == 200, r.text
    assert r.headers["x-mask"] == "network" and crop_box(r) == true_box(mask) == box
    got = Image.open(io.BytesIO(post(fg_client, png(img), debug="mask").content))
    assert got.size == (w, h)


def _encoded(img: Image.Image, fmt: str) -> bytes:
    buf = io.BytesIO()
    img.save(buf, format=fmt, **({"quality": 95} if fmt == "JPEG" else {}))
    return buf.getvalue()


def test_16_bit_greyscale_and_cmyk_photos(fg_client, segment_calls):
    img, mask = scene()
    grey = Image.fromarray((img.mean(axis=2) * 257).astype(np.uint16))
    assert grey.mode == "I;16"
    cmyk = Image.fromarray(img).convert("CMYK")
    for data in (_encoded(grey, "PNG"), _encoded(cmyk, "JPEG")):
        r = post(fg_client, data)
        assert r.status_code == 200, r.text
        assert r.headers["x-mask"] == "network"
        assert np.abs(np.subtract(crop_box(r), true_box(mask))).max() <= 2


def test_a_heic_phone_photo(fg_client, segment_calls):
    """HEIC, what phones save when they do not save JPEG, read like a JPEG (a lying file name and
    type change nothing)."""
    img, mask = scene()
    data = _encoded(Image.fromarray(img), "HEIF")
    assert data[4:12] == b"ftypheic"
    r = fg_client.post("/v1/image-to-shape", files={"image": ("p.png", data, "image/png")})
    assert r.status_code == 200, r.text
    assert r.headers["x-mask"] == "network" and len(segment_calls) >= 1
    assert np.abs(np.subtract(crop_box(r), true_box(mask))).max() <= 2


def test_the_real_foreground_graph_runs(fg_client, foreground_models_dir):
    """No patch: the bundle's ONNX foreground network (random weights, its head biased to "object")."""
    img, _ = scene(120, 200)
    r = post(fg_client, png(img), debug="mask")
    assert r.status_code == 200, r.text
    assert r.headers["x-mask"] == "network" and r.headers["x-crop-box"] == "0,0,200,120"
    assert "mask" in stages(r)
    got = np.asarray(Image.open(io.BytesIO(r.content)), np.float32)
    runtime = Runtime(load_bundle(foreground_models_dir / "image-to-shape"), threads=1)
    grid = runtime.segment(img)
    direct = to_image(img, grid, runtime.bundle.mask_spec())
    assert grid.shape == (64, 64) and got.shape == direct.shape == (120, 200)
    assert np.abs(got - direct * 255).max() <= 1.01 and got.min() > 200
    mesh = post(fg_client, png(img))
    assert mesh.status_code == 200 and mesh.headers["x-mask"] == "network"


def test_models_reports_the_foreground_network_and_ratio(client, fg_client):
    def image_model(c) -> dict:
        return next(m for m in c.get("/v1/models").json()["models"] if m["task"] == "image-to-shape")

    assert image_model(fg_client)["foreground_network"] is True
    assert image_model(client)["foreground_network"] is False
    assert image_model(client)["foreground_ratio"] == image_model(fg_client)["foreground_ratio"] == 0.9
    others = [m for m in client.get("/v1/models").json()["models"] if m["task"] != "image-to-shape"]
    assert others and all(m["foreground_network"] is None and m["foreground_ratio"] is None for m in others)


@pytest.mark.parametrize("fmt", ["JPEG", "PNG"])
def test_a_large_photo_is_worked_on_reduced_and_answered_in_its_own_pixels(fg_client, segment_calls, fmt):
    """A 1600 x 2400 photo (short side over the working size): the network sees it reduced to 1024 on
    its short side, the crop box and the debug mask come back in the upload's pixels."""
    img, mask = scene(160, 240, (40, 90, 110, 170))
    big = np.asarray(Image.fromarray(img).resize((2400, 1600), Image.Resampling.NEAREST))
    data = _encoded(Image.fromarray(big), fmt)
    r = post(fg_client, data)
    assert r.status_code == 200, r.text
    assert segment_calls[0].shape[:2] == (1024, 1536)                     # then a second look at its square
    assert all(max(c.shape[:2]) <= 1536 for c in segment_calls)
    want = tuple(10 * v for v in true_box(mask))                # the object's box in the upload's pixels
    assert np.abs(np.subtract(crop_box(r), want)).max() <= 4
    got = post(fg_client, data, debug="mask")
    assert got.status_code == 200 and crop_box(got) == crop_box(r)
    m = np.asarray(Image.open(io.BytesIO(got.content))) > 127
    assert m.shape == (1600, 2400)
    big_mask = np.asarray(Image.fromarray(mask).resize((2400, 1600), Image.Resampling.NEAREST))
    assert (m & big_mask).sum() / (m | big_mask).sum() > 0.97


def test_a_box_prompt_looks_for_the_object_inside_it_only(fg_client, segment_calls):
    """box=left,top,right,bottom: the mask is the object inside the box (a second object outside
    it is not taken, though the network sees the box with some context about it), X-Crop-Box says
    the object's box in the same order, and the mask's confidence is reported."""
    img, mask = scene(160, 240, box=(40, 30, 110, 100))
    second, other = scene(160, 240, box=(50, 150, 120, 220), seed=1)
    img[other] = second[other]                                 # another object to the right
    r = post(fg_client, png(img), debug="mask", box="20,20,120,130")
    assert r.status_code == 200, r.text
    got = np.asarray(Image.open(io.BytesIO(r.content))) > 127
    assert got[other].mean() == 0 and got[mask].mean() > 0.95
    assert np.abs(np.subtract(crop_box(r), true_box(mask))).max() <= 2
    assert 0 <= float(r.headers["x-mask-confidence"]) <= 1
    # the network sees the box with half its longest side (110) about it, clipped to the photo: rows 0-160,
    # columns 0-175, so part of the second object too, which the mask still leaves out
    assert segment_calls[0].shape[:2] == (160, 20 + 100 + 55)
    whole = post(fg_client, png(img), debug="mask")             # without the box: both objects
    both = np.asarray(Image.open(io.BytesIO(whole.content))) > 127
    assert both[other].mean() > 0.95


def test_bad_boxes_get_a_clear_422(fg_client, segment_calls):
    img, _ = scene(160, 200)
    r = post(fg_client, png(img), box="0,0,60,30")             # background only: above the object
    assert r.status_code == 422 and r.json()["error"]["code"] == "no_object"
    assert "the box holds no object" in r.json()["error"]["message"]
    assert "box" in r.json()["error"]["hint"]
    for box, code in (("300,300,400,400", "invalid_box"), ("50,50,10,10", "invalid_box"),
                      ("1,2,3", "invalid_request"), ("a,b,c,d", "invalid_request")):
        r = post(fg_client, png(img), box=box)
        assert r.status_code == 422 and r.json()["error"]["code"] == code, (box, r.text)
    clipped = post(fg_client, png(img), box="-50,-50,500,500", debug="mask")   # beyond the image: clipped
    assert clipped.status_code == 200, clipped.text


def test_a_box_without_background_removal_is_the_crop_and_alpha_still_wins(fg_client, segment_calls, encoder_inputs):
    img, mask = scene(160, 200)
    r = post(fg_client, png(img), remove_background="false", box="80,30,180,120")
    assert r.status_code == 200, r.text
    assert r.headers["x-mask"] == "none" and r.headers["x-crop-box"] == "80,30,180,120" and not segment_calls
    assert "x-mask-confidence" not in r.headers
    rgba = np.dstack([img, np.where(mask, 255, 0).astype(np.uint8)])
    r = post(fg_client, png(rgba), box="0,0,200,160")
    assert r.status_code == 200 and r.headers["x-mask"] == "alpha" and not segment_calls
    assert np.abs(np.subtract(crop_box(r), true_box(mask))).max() <= 1


def test_the_warm_up_runs_the_foreground_network_and_compiles_the_guided_filters_kernel(foreground_models_dir, tmp_path):
    """A fresh process with a foreground network whose masks go through the guided filter: after
    the warm-up the filter's compiled blend, the edge band, the composite and the network input's
    passes (for a photo as decoded and for the views cut from it, wide and tall) have their machine
    code (a first photo does not spend seconds compiling them)."""
    shutil.copytree(foreground_models_dir, tmp_path / "models")
    meta_path = tmp_path / "models" / "image-to-shape" / "model.json"
    meta = json.loads(meta_path.read_text())
    meta["input"]["foreground"]["guide"] = 1.0
    meta_path.write_text(json.dumps(meta))
    code = ("import sys; from service.engine import Engine; from service.settings import Settings; "
            "from model.image import frame, mask, resample; e = Engine(Settings(models_dir=sys.argv[1])); e.load(); "
            "ks = (mask._blend, mask._edge_band, frame._composite, resample._across, resample._down); "
            "before = [len(k.signatures) for k in ks]; e.warm_up(); print([before, [len(k.signatures) for k in ks]])")
    out = subprocess.run([sys.executable, "-c", code, str(tmp_path / "models")], capture_output=True, text=True,
                         timeout=600, cwd=REPO)
    assert out.returncode == 0, out.stderr[-2000:]
    before, after = json.loads(out.stdout.strip().splitlines()[-1])
    assert before == [0, 0, 0, 0, 0], out.stdout
    # one version per array layout a request brings: the blend's arrays are made contiguous; the
    # edge band's and the composite's part and canvas are strided or whole rows; the network
    # input's passes read the photo as decoded or a strided crop
    assert after == [1, 2, 4, 2, 2], out.stdout
