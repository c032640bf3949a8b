"""The foreground network trained, resumed and exported into an image bundle; an image model
retrained for photos from an image teacher; the photo-like evaluation."""

from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from export.parity import RELATIVE_TOLERANCE
from model.image.frame import prepare_image
from model.networks.foreground import ForegroundNet, mask_losses
from model.train.loop import Trainer

from .test_train import config, trains_and_resumes_identically

FG = dict(task="foreground", arch="unet", encoder_width=4, image_size=32)
IMAGE = dict(task="image", arch="aocnn", encoder="lenet", encoder_width=4, image_size=32)


def test_the_network_is_compact_and_maps_images_to_logits():
    net = ForegroundNet()
    assert sum(p.numel() for p in net.parameters()) <= 3_000_000
    assert net(torch.zeros(2, 3, 64, 48)).shape == (2, 1, 64, 48)
    with pytest.raises(ValueError):
        ForegroundNet(width=0)


def test_the_light_network_maps_images_to_logits_for_a_fifth_of_the_work():
    from torch.utils.flop_counter import FlopCounterMode

    from model.networks.foreground import LiteForegroundNet

    def flops(net):
        with FlopCounterMode(display=False) as count:
            net(torch.zeros(1, 3, 128, 128))
        return count.get_total_flops()

    lite = LiteForegroundNet(16).eval()
    assert sum(p.numel() for p in lite.parameters()) <= 3_000_000
    assert lite(torch.zeros(2, 3, 64, 96)).shape == (2, 1, 64, 96)
    assert flops(lite) < 0.25 * flops(ForegroundNet(16).eval())
    with pytest.raises(ValueError, match="width >= 2"):
        LiteForegroundNet(width=1)


def test_the_losses_reward_the_right_mask():
    truth = torch.zeros(1, 1, 8, 8)
    truth[..., 2:6, 2:6] = 1
    right, wrong = mask_losses(truth * 20 - 10, truth), mask_losses(10 - truth * 20, truth)
    assert right["iou"] == pytest.approx(1.0) and wrong["iou"] == pytest.approx(0.0, abs=1e-6)
    assert right["total"] < 0.01 < 1.5 < wrong["total"]


def test_skeletons_follow_thin_parts_inside_the_object():
    from model.train.foreground import tubed_skeletons

    masks = np.zeros((3, 1, 64, 64), np.float32)
    masks[0, 0, 10:40, 10:50] = 1                        # a seat
    masks[0, 0, 40:62, 12:14] = masks[0, 0, 40:62, 46:48] = 0.9  # two legs, 2 px wide
    masks[1, 0, 20:30, 20:30] = 0.4                      # coverage below one half: no object
    s = tubed_skeletons(masks)
    assert s.dtype == np.float32 and set(np.unique(s)) <= {0.0, 1.0}
    assert s[1:].sum() == 0 and s[0].sum() > 0
    assert np.all(s[0, 0][masks[0, 0] <= 0.5] == 0)      # the tube is cut to the object
    for left in (12, 46):                                # each leg's skeleton runs most of its length
        assert s[0, 0, 42:60, left:left + 2].any(axis=1).all()


def test_the_skeleton_recall_loss_prices_a_lost_leg_above_its_area():
    from model.train.foreground import tubed_skeletons

    truth = np.zeros((1, 1, 64, 64), np.float32)
    truth[..., 10:40, 10:50] = 1
    truth[..., 40:62, 12:14] = 1                         # a 2-px leg: 44 of 1,244 pixels
    skel = torch.from_numpy(tubed_skeletons(truth))
    truth = torch.from_numpy(truth)
    no_leg = truth.clone()
    no_leg[..., 40:62, 12:14] = 0
    thin_body = truth.clone()
    thin_body[..., 10:12, 10:50] = 0                     # as many pixels lost from the seat's edge (80)
    lose_leg = mask_losses(no_leg * 20 - 10, truth, skel, 1.0)
    lose_edge = mask_losses(thin_body * 20 - 10, truth, skel, 1.0)
    assert lose_leg["dice"] < lose_edge["dice"]          # by area the leg costs less ...
    assert lose_leg["skeleton"] > 0.2 > 0.05 > lose_edge["skeleton"]  # ... by skeleton far more
    assert lose_leg["total"] > lose_edge["total"]
    plain = mask_losses(no_leg * 20 - 10, truth)
    assert "skeleton" not in plain and float(lose_leg["total"] - plain["total"]) == pytest.approx(
        float(lose_leg["skeleton"]))
    empty = torch.zeros_like(truth)                      # no object: no skeleton, no skeleton loss
    assert float(mask_losses(empty - 10, empty, torch.zeros_like(empty), 1.0)["skeleton"]) == 0.0


def test_a_network_trained_for_thin_parts_gets_skeletons_and_keeps_its_weight(tiny_data, tmp_path):
    t = Trainer(config(tiny_data, tmp_path / "skel", iters=2, skeleton_weight=1.0, **FG))
    images, masks, skeletons = t.task.inputs(t.cfg, t.train_set, t.batch_indices(0), np.random.default_rng(0))
    assert skeletons.shape == masks.shape and 0 < float(skeletons.sum()) < float((masks > 0.5).sum())
    summary = t.run()
    assert 0 <= summary["val"]["skeleton"] <= 1
    with pytest.raises(ValueError, match="skeleton_weight"):
        Trainer(config(tiny_data, tmp_path / "skel", iters=4, skeleton_weight=2.0, **FG))
    with pytest.raises(ValueError, match="--skeleton-weight"):
        Trainer(config(tiny_data, tmp_path / "bad", skeleton_weight=-1.0, **FG))


def test_foreground_training_resumes_to_identical_weights_and_reports_iou(tiny_data, tmp_path):
    _, summary = trains_and_resumes_identically(tiny_data, tmp_path, **FG)
    assert 0 <= summary["val"]["iou"] <= 1 and np.isfinite(summary["val"]["total"])
    t = Trainer(config(tiny_data, tmp_path / "a", **FG))
    idx = t.batch_indices(0)
    images, masks = t.task.inputs(t.cfg, t.train_set, idx, np.random.default_rng(0))
    assert images.shape == (len(idx), 3, 32, 32) and masks.shape == (len(idx), 1, 32, 32)
    assert 0 < float(masks.mean()) < 1                  # an object on a background, not all or nothing
    with pytest.raises(ValueError, match="multiple of 16"):
        Trainer(config(tiny_data, tmp_path / "bad", **{**FG, "image_size": 40}))


def test_the_light_network_trains_resumes_and_exports_as_the_bundle_runs_it(tiny_data, tmp_path):
    from export.bundle import load_bundle
    from export.exporter import export
    from export.runtime import Runtime
    from model.checkpoint import load_model
    from model.image.mask import MaskSpec, mask_input, mask_output
    from model.networks.foreground import LiteForegroundNet

    lite = {**FG, "arch": "unet-lite"}
    straight, summary = trains_and_resumes_identically(tiny_data, tmp_path, **lite)
    assert isinstance(straight.model.net, LiteForegroundNet) and 0 <= summary["val"]["iou"] <= 1
    img = tmp_path / "img"
    Trainer(config(tiny_data, img, iters=1, **IMAGE)).run()
    meta = export(img, tmp_path / "bundle", foreground=tmp_path / "a", foreground_precision="float32")
    assert meta["export"]["self_check"]["foreground_relative_error"] <= RELATIVE_TOLERANCE
    rgb = np.random.default_rng(1).integers(0, 256, (50, 30, 3), dtype=np.uint8)
    with torch.no_grad():
        logits = load_model(tmp_path / "a").model.net(torch.from_numpy(mask_input(rgb, MaskSpec(size=32))[None]))
    p = Runtime(load_bundle(tmp_path / "bundle"), threads=1).segment(rgb)
    assert p.shape == (32, 32) and np.abs(mask_output(logits.numpy()[0, 0]) - p).max() < 1e-4
    with pytest.raises(ValueError, match="multiple of 32"):
        Trainer(config(tiny_data, tmp_path / "bad", **{**lite, "image_size": 48}))
    with pytest.raises(ValueError, match="unknown foreground network"):
        Trainer(config(tiny_data, tmp_path / "bad", **{**FG, "arch": "segformer"}))


def test_a_second_looks_view_is_the_objects_square_cut_from_the_photo():
    from model.data.photos import Photo, mask_box
    from model.image.mask import MaskSpec
    from model.train.foreground import BOX_ERROR, second_look

    spec = MaskSpec(size=32)
    rgb = np.random.default_rng(0).integers(0, 256, (300, 400, 3), dtype=np.uint8)
    mask = np.zeros((300, 400), np.float32)
    mask[200:240, 300:360] = 1                           # a 40 x 60 object off-centre
    photo = Photo(rgb, mask, mask_box(mask))
    for seed in range(20):
        view = second_look(photo, np.random.default_rng(seed), spec)
        h, w = view.mask.shape
        assert h == w and 60 * (1 + 2 * spec.refine_margin) * (1 - 2 * BOX_ERROR) <= h <= 60 * 1.4 * (1 + 2 * BOX_ERROR) + 1
        assert view.mask.sum() == mask.sum()             # the whole object, cut with its pixels
        top, left = next((y, x) for y in range(300 - h + 1) for x in range(400 - w + 1)
                         if np.array_equal(rgb[y:y + h, x:x + w], view.rgb))
        assert np.array_equal(view.mask, mask[top:top + h, left:left + w])
    big = mask.copy()
    big[20:280, 40:360] = 1                              # the square would cover most of the photo
    assert second_look(Photo(rgb, big, mask_box(big)), np.random.default_rng(0), spec).rgb is rgb
    empty = Photo(rgb, np.zeros_like(mask), None)
    assert second_look(empty, np.random.default_rng(0), spec) is empty


def test_a_network_trained_on_second_looks_looks_again_at_small_squares(tiny_data, tmp_path):
    from model.train.tasks import TRAINED_REFINE_MIN

    t = Trainer(config(tiny_data, tmp_path / "crops", iters=2, crop_share=1.0, **FG))
    plain = Trainer(config(tiny_data, tmp_path / "plain", iters=2, **FG))
    assert plain.task.spec(plain.cfg).refine_side == 32 and t.task.spec(t.cfg).refine_side == TRAINED_REFINE_MIN
    idx = t.batch_indices(0)
    a, _ = t.task.inputs(t.cfg, t.train_set, idx, np.random.default_rng(0))
    b, _ = plain.task.inputs(plain.cfg, plain.train_set, idx, np.random.default_rng(0))
    assert a.shape == b.shape and not torch.equal(a, b)
    with pytest.raises(ValueError, match="--crop-share"):
        Trainer(config(tiny_data, tmp_path / "bad", crop_share=1.5, **FG))


def test_a_run_started_from_another_runs_weights(tiny_data, runs, tmp_path, capsys):
    """--init: a new run starts from another's weights (the same task and network), records where
    they came from, and research.release carries that into model.json; a run that does not fit is refused."""
    from model.train.__main__ import main
    from research.recipe import load_recipe
    from research.release import package

    Trainer(config(tiny_data, tmp_path / "a", iters=2, **FG)).run()
    source = torch.load(tmp_path / "a" / "checkpoint.pt", weights_only=False)["model"]
    tuned = Trainer(config(tiny_data, tmp_path / "b", iters=2, init=str(tmp_path / "a"), crop_share=0.5, **FG))
    assert tuned.step == 0 and all(torch.equal(tuned.model.state_dict()[k], v) for k, v in source.items())
    assert json.loads((tmp_path / "b" / "config.json").read_text())["init"] == str(tmp_path / "a")
    assert json.loads((tmp_path / "b" / "init.json").read_text()) == {"path": str(tmp_path / "a"),
                                                                      "weights_sha256": None, "steps": 2}
    tuned.run()
    meta = package(tmp_path / "b", tiny_data, tmp_path / "shipped", load_recipe("foreground"), ["foreground"], by_recipe=False)
    assert meta["init"]["path"] == str(tmp_path / "a") and meta["config"]["crop_share"] == 0.5
    kept = sorted((tmp_path / "b" / "steps").iterdir())[-1]       # a step the run kept: its run's init
    assert package(kept, tiny_data, tmp_path / "kept", load_recipe("foreground"), ["foreground"],
                   by_recipe=False)["init"] == meta["init"]
    assert package(tmp_path / "a", tiny_data, tmp_path / "scratch", load_recipe("foreground"), ["foreground"],
                   by_recipe=False)["init"] is None
    fresh = Trainer(config(tiny_data, tmp_path / "c", iters=2, **FG)).model.state_dict()
    assert any(not torch.equal(fresh[k], v) for k, v in source.items() if v.is_floating_point())
    args = ["foreground", "--data", str(tiny_data), "--depth", "5", "--out", str(tmp_path / "d"), "--quiet",
            "--image-size", "32", "--iters", "1"]
    with pytest.raises(ValueError, match="--init and --teacher"):
        Trainer(config(tiny_data, tmp_path / "e", **{**IMAGE, "init": str(runs / "img"), "teacher": str(runs / "img")}))
    for init, needle in ((tmp_path / "a", "encoder_width=4"), (tmp_path / "none", "neither a run folder")):
        assert main(args + ["--init", str(init)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and needle in err[0]


@pytest.fixture(scope="module")
def runs(tiny_data, tmp_path_factory):
    root = tmp_path_factory.mktemp("fg_runs")
    Trainer(config(tiny_data, root / "fg", iters=3, **FG)).run()
    Trainer(config(tiny_data, root / "img", iters=3, **IMAGE)).run()
    return root


@pytest.fixture(scope="module")
def float32_bundle(runs, tmp_path_factory):
    """(folder, model.json) of the bundle of ``runs``' image model with its foreground network in
    float32: exported once for the tests that only read it."""
    from export.exporter import export

    out = tmp_path_factory.mktemp("fg_bundle") / "b"
    return out, export(runs / "img", out, foreground=runs / "fg", foreground_precision="float32")


def test_an_image_model_retrained_for_photos_starts_from_its_teacher(tiny_data, runs, tmp_path):
    kw = dict(IMAGE, iters=4, teacher=str(runs / "img"), photo_share=0.5, foreground_ratio=0.85)
    student = Trainer(config(tiny_data, tmp_path / "s", **kw))
    teacher = Trainer(config(tiny_data, runs / "img", iters=3, **IMAGE)).model.eval()
    s0, t0 = student.model.state_dict(), teacher.state_dict()
    assert all(torch.equal(s0[k], t0[k]) for k in t0)                 # starts as the teacher
    # the targets: the teacher's code of every view, on the plain background at its own framing
    codes = student.train_set.latents
    first = student.train_set.samples[0]
    assert codes.shape == (len(student.train_set), len(first.images), 32)
    with torch.no_grad():
        want = teacher.encoder(torch.from_numpy(np.stack([prepare_image(v, teacher_spec()) for v in first.images])))
    assert torch.allclose(codes[0], want, atol=1e-5)
    assert student.task.spec(student.cfg).foreground_ratio == pytest.approx(0.85)
    student.run()
    dec_s, dec_t = student.model.decoder.state_dict(), teacher.decoder.state_dict()
    assert all(torch.equal(dec_s[k], dec_t[k]) for k in dec_t)
    assert any(not torch.equal(student.model.encoder.state_dict()[k], teacher.encoder.state_dict()[k])
               for k in teacher.encoder.state_dict() if teacher.encoder.state_dict()[k].is_floating_point())
    with pytest.raises(ValueError, match="image_size"):
        Trainer(config(tiny_data, tmp_path / "bad", **{**kw, "image_size": 48}))


def teacher_spec():
    from model.image.frame import ImageSpec
    return ImageSpec(size=32)


def test_the_bundle_carries_the_foreground_network_and_the_photo_evaluation_uses_it(tiny_data, runs, float32_bundle,
                                                                                   tmp_path):
    from export.bundle import BundleError, load_bundle
    from export.exporter import export
    from export.runtime import Runtime
    from model.checkpoint import load_model
    from research.evaluate import EvalOptions, evaluate

    bundle, meta = float32_bundle
    assert "foreground" in meta["graphs"] and meta["input"]["foreground"]["size"] == 32
    check = meta["export"]["self_check"]
    assert check["foreground_relative_error"] <= RELATIVE_TOLERANCE and check["foreground_pixel_agreement"] >= 0.999
    assert meta["export"]["quantized"] is False and meta["export"]["foreground_precision"] == "float32"
    rt = Runtime(load_bundle(bundle), threads=1)
    rgb = np.random.default_rng(0).integers(0, 256, (40, 70, 3), dtype=np.uint8)
    p = rt.segment(rgb)
    assert p.shape == (32, 32) and 0 <= p.min() and p.max() <= 1           # the network's grid
    from model.image.mask import MaskSpec, mask_input, mask_output
    with torch.no_grad():
        logits = load_model(runs / "fg").model.net(torch.from_numpy(mask_input(rgb, MaskSpec(size=32))[None]))
    assert np.abs(mask_output(logits.numpy()[0, 0]) - p).max() < 1e-4
    with pytest.raises(BundleError, match="foreground network"):
        export(runs / "img", tmp_path / "c", foreground=runs / "img")
    with pytest.raises(BundleError, match="precision"):
        export(runs / "img", tmp_path / "c", foreground=runs / "fg", foreground_precision="int4")
    assert not (tmp_path / "c").exists()
    res = evaluate(str(runs / "img"), str(tiny_data),
                   EvalOptions("train", resolution=16, limit=3, bundle=str(bundle), photos=True))
    assert res["input"]["foreground_network"] and sum(res["input"]["mask_sources"].values()) == 3
    for r in res["per_shape"]:
        assert r["mask_source"] in ("network", "missed")
        assert 0 <= r["mask_iou"] <= 1 and len(r["photo_size"]) == 2
    plain = evaluate(str(runs / "img"), str(tiny_data), EvalOptions("train", resolution=16, limit=3, photos=True))
    assert plain["input"] == {"kind": "photos", "remove_background": "auto", "foreground_network": False,
                              "foreground": None, "exact_masks": False, "box_prompts": False,
                              "mask_sources": {"none": 3}}
    json.dumps(res)
    # the diagnostic: each photo sent with its exact mask as alpha, what a perfect foreground network gives
    exact = evaluate(str(runs / "img"), str(tiny_data),
                     EvalOptions("train", resolution=16, limit=3, bundle=str(bundle), photos=True, exact_masks=True))
    assert exact["input"]["mask_sources"] == {"alpha": 3} and not exact["input"]["foreground_network"]
    assert all(r["mask_iou"] > 0.99 for r in exact["per_shape"])
    assert exact["mask_iou_category_mean"] >= res["mask_iou_category_mean"]
    # with a box prompt about each object (5% larger): the masks stay inside it, the IoU is measured as before
    boxed = evaluate(str(runs / "img"), str(tiny_data),
                     EvalOptions("train", resolution=16, limit=3, bundle=str(bundle), photos=True, box_prompts=True))
    assert boxed["input"]["box_prompts"] and sum(boxed["input"]["mask_sources"].values()) == 3
    assert all(0 <= r["mask_iou"] <= 1 for r in boxed["per_shape"])
    import dataclasses

    from model.data.photos import box_prompt, photo_split_view
    from model.train.tasks import TASKS
    cfg = dataclasses.replace(load_model(runs / "img").config, data=str(tiny_data))
    views = {s.shape_id: photo_split_view(s.images, s.shape_id) for s in TASKS["image"].dataset(cfg, "train", 0, limit=3).samples}
    for r in boxed["per_shape"]:                          # each mask (or crop, where missed) inside its prompt
        left, top, right, bottom = box_prompt(views[r["shape_id"]].mask)
        assert top <= r["box"][0] and left <= r["box"][1] and r["box"][2] <= bottom and r["box"][3] <= right
    with pytest.raises(ValueError, match="--box-prompt goes with --photos"):
        evaluate(str(runs / "img"), str(tiny_data), EvalOptions("train", resolution=16, limit=3, box_prompts=True))
    for bad in (dict(photos=False), dict(photos=True, foreground=str(runs / "fg"))):
        with pytest.raises(ValueError, match="--exact-masks"):
            evaluate(str(runs / "img"), str(tiny_data), EvalOptions("train", resolution=16, limit=3, exact_masks=True, **bad))


def test_the_default_bundle_stores_the_foreground_network_in_int8_and_it_masks_as_torch_does(runs, float32_bundle,
                                                                                          tmp_path):
    """Static int8 quantisation (QDQ): the convolutions' weights are int8 in the file, the file is
    smaller, and the masks agree with torch's on photos it was not calibrated with."""
    import onnx

    from export.bundle import load_bundle
    from export.exporter import FOREGROUND_INT8_AGREEMENT, export, foreground_photos
    from export.runtime import Runtime
    from model.checkpoint import load_model

    meta = export(runs / "img", tmp_path / "q", foreground=runs / "fg")
    assert meta["export"]["quantized"] == ["foreground"] and meta["export"]["foreground_precision"] == "int8"
    assert meta["export"]["self_check"]["foreground_pixel_agreement"] >= FOREGROUND_INT8_AGREEMENT
    bundle = load_bundle(tmp_path / "q")
    graph = onnx.load(bundle.file("foreground"))
    ops = {n.op_type for n in graph.graph.node}
    assert {"QuantizeLinear", "DequantizeLinear", "Conv"} <= ops
    int8 = [t for t in graph.graph.initializer if t.data_type == onnx.TensorProto.INT8 and len(t.dims) == 4]
    assert len(int8) == sum(n.op_type == "Conv" for n in graph.graph.node) > 0     # every convolution's weights
    weights = np.concatenate([onnx.numpy_helper.to_array(t).ravel() for t in int8])
    assert -64 <= weights.min() and weights.max() <= 64      # 7 bits: the same masks with and without VNNI
    assert meta["export"]["foreground_int8"].endswith("(reduce_range)")
    folder, float32 = float32_bundle
    assert bundle.file("foreground").stat().st_size < 0.6 * load_bundle(folder).file("foreground").stat().st_size
    _, check = foreground_photos(32)
    rt = Runtime(bundle, threads=1)
    ours = np.concatenate([rt.run("foreground", {"image": x})[0] for x in check])
    with torch.no_grad():
        theirs = load_model(runs / "fg").model.net(torch.from_numpy(np.concatenate(check))).numpy()
    assert np.mean((ours > 0) == (theirs > 0)) >= FOREGROUND_INT8_AGREEMENT
    assert float32["export"]["self_check"]["foreground_relative_error"] <= RELATIVE_TOLERANCE


def test_photo_inputs_are_framed_objects_for_any_draw():
    """The image model's photo samples: the object cut out again with a degraded mask and framed
    (every draw, small objects and objects at the border included), not the scene."""
    from model.image.frame import ImageSpec
    from model.train.images import photo_input

    rgba = np.zeros((137, 137, 4), np.uint8)
    rgba[20:120, 50:90] = (30, 30, 200, 255)
    spec = ImageSpec(size=32)
    for seed in range(40):
        x = photo_input(rgba, spec, np.random.default_rng(seed))
        assert x.shape == (3, 32, 32) and np.isfinite(x).all()
        rgb = x.transpose(1, 2, 0) * 0.25 + 0.5
        blue = (rgb[..., 2] - rgb[..., 0]) > 0.15
        assert blue[12:20, 14:18].mean() > 0.5          # the object is in the middle of the input


def test_the_guided_filter_is_calibrated_on_validation_recorded_and_exported(tiny_data, runs, float32_bundle, tmp_path,
                                                                            capsys):
    """``--mask-guide`` scores every candidate on the split's photo-like views, keeps the best, writes
    mask_guide.json (a run) or model.json (a checkpoint folder); evaluation and export take it."""
    import shutil

    from export.bundle import load_bundle
    from export.exporter import export
    from research.calibrate import MASK_GUIDE_EPS, MASK_GUIDE_RADII, main
    from research.evaluate import EvalOptions, evaluate

    run = tmp_path / "fg"
    shutil.copytree(runs / "fg", run)
    assert main([str(run), "--data", str(tiny_data), "--split", "train", "--mask-guide", "--limit", "3"]) == 0
    assert "guided filter radius" in capsys.readouterr().out
    report = json.loads((run / "mask_guide.json").read_text())
    scores = [c["mask_iou_category_mean"] for c in report["candidates"]]
    assert len(scores) == 1 + (len(MASK_GUIDE_RADII) - 1) * len(MASK_GUIDE_EPS)
    assert report["mask_iou_category_mean"] == max(scores) and report["photos"] == 3
    best = report["candidates"][int(np.argmax(scores))]
    assert (report["radius"], report["eps"]) == (best["radius"], best["eps"])
    res = evaluate(str(run), str(tiny_data), EvalOptions("train", limit=3))
    assert res["mask_spec"]["guide"] == report["radius"] and res["mask_spec"]["guide_eps"] == report["eps"]
    assert res["mask_iou_category_mean"] == pytest.approx(report["mask_iou_category_mean"], abs=1e-4)
    meta = export(runs / "img", tmp_path / "b", foreground=run, foreground_precision="float32")
    spec = load_bundle(tmp_path / "b").mask_spec()
    assert (spec.guide, spec.guide_eps) == (report["radius"], report["eps"])
    assert meta["version"] != float32_bundle[1]["version"]   # the same networks unguided: what is served differs
    assert main([str(runs / "img"), "--data", str(tiny_data), "--mask-guide"]) == 2
    assert "foreground network" in capsys.readouterr().err


def test_photos_without_a_bundle_take_the_foreground_network_in_torch_as_its_bundle_would(tiny_data, runs,
                                                                                         float32_bundle):
    from research.evaluate import EvalOptions, evaluate

    bundle, _ = float32_bundle
    kw = dict(resolution=16, limit=3, photos=True)
    served = evaluate(str(runs / "img"), str(tiny_data), EvalOptions("train", bundle=str(bundle), **kw))
    torch_fg = evaluate(str(runs / "img"), str(tiny_data), EvalOptions("train", foreground=str(runs / "fg"), **kw))
    assert torch_fg["input"]["foreground_network"] and torch_fg["input"]["foreground"] == str(runs / "fg")
    assert torch_fg["input"]["mask_sources"] == served["input"]["mask_sources"]
    for a, b in zip(torch_fg["per_shape"], served["per_shape"]):
        assert a["mask_iou"] == pytest.approx(b["mask_iou"], abs=1e-3)
        assert a["box"] == b["box"]
    for bad, needle in ((dict(kw, photos=False), "goes with --photos"),
                        (dict(kw, bundle=str(bundle)), "no --bundle")):
        with pytest.raises(ValueError, match=needle):
            evaluate(str(runs / "img"), str(tiny_data), EvalOptions("train", foreground=str(runs / "fg"), **bad))
    with pytest.raises(ValueError, match="not a foreground network"):
        evaluate(str(runs / "img"), str(tiny_data), EvalOptions("train", foreground=str(runs / "img"), **kw))


def test_a_model_retrained_for_photos_is_chosen_on_the_validation_photos(tiny_data, runs, tmp_path, capsys):
    from research.choose import main
    from research.curves import foreground_fingerprint
    from research.evaluate import EvalOptions, evaluate

    run, out = tmp_path / "s", tmp_path / "best"
    Trainer(config(tiny_data, tmp_path / "fg2", iters=2, **FG)).run()
    # an autoencoder teacher trained long enough that its decoder's outputs are not empty
    Trainer(config(tiny_data, tmp_path / "ae", iters=16, val_every=8, ckpt_every=8)).run()
    Trainer(config(tiny_data, run, **dict(IMAGE, iters=4, val_every=2, teacher=str(tmp_path / "ae"),
                                            photo_share=0.5, foreground_ratio=0.85))).run()
    args = [str(run), "--data", str(tiny_data), "--out", str(out), "--per-category", "1", "--resolution", "16"]
    assert main([*args, "--photos", str(runs / "fg")]) == 0
    assert "on photos" in capsys.readouterr().out
    kept = {}
    for step in (2, 4):
        folder = run / "steps" / f"{step:06d}"
        assert not (folder / "chamfer.json").exists()              # the clean figures are another file
        kept[step] = json.loads((folder / "chamfer-photos.json").read_text())["chamfer_x1e3"]
        again = evaluate(str(folder), str(tiny_data),
                         EvalOptions("val", resolution=16, per_category=1, photos=True, foreground=str(runs / "fg")))
        assert again["chamfer_x1e3_category_mean"] == pytest.approx(kept[step])
    meta = json.loads((out / "model.json").read_text())
    assert meta["steps"] == min(kept, key=lambda s: (kept[s], s))
    assert meta["chosen"]["foreground"] == str((runs / "fg").resolve()) and "photo-like" in meta["chosen"]["rule"]
    for bad, needle in ((tmp_path / "none", "neither a run folder"), (run, "not a foreground network")):
        assert main([*args, "--photos", str(bad)]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1
    # the figures are kept with what decides the masks: another foreground network measures again
    fingerprint = json.loads((run / "steps" / "000002" / "chamfer-photos.json").read_text())["settings"]["foreground"]
    assert fingerprint == foreground_fingerprint(runs / "fg") != foreground_fingerprint(tmp_path / "fg2")


def test_thin_parts_are_the_objects_pixels_near_the_background():
    from model.train.foreground import thin_parts

    m = np.zeros((1, 1, 100, 100), np.float32)
    m[0, 0, 10:90, 10:60] = 1                            # a body 80 x 50
    m[0, 0, 40:42, 60:90] = 1                            # a rod two pixels thick
    thin = thin_parts(m)[0, 0] > 0
    assert thin[40:42, 62:90].all()                      # the whole rod is thin
    assert not thin[30:70, 20:50].any()                  # the body's middle is not
    assert thin[10, 10:60].all() and not (thin & (m[0, 0] == 0)).any()   # its rim is; never the background


def test_the_refinement_trains_on_the_first_networks_mask_of_the_objects_square(tiny_data, runs, tmp_path):
    """Its inputs are the object's square at the refinement's side with the first network's mask
    as a fourth channel in [-1, 1], its targets the exact mask over the square; it trains and
    reports the thin parts' recall."""
    refine = dict(task="refine", arch="unet-lite", encoder_width=4, image_size=64, skeleton_weight=1.0,
                  teacher=str(runs / "fg"))
    t = Trainer(config(tiny_data, tmp_path / "r", iters=2, val_every=2, ckpt_every=2, **refine))
    summary = t.run()
    assert 0 <= summary["val"]["thin_recall"] <= 1 and 0 <= summary["val"]["iou"] <= 1
    images, masks, skeletons, thin = t.task.inputs(t.cfg, t.train_set, t.batch_indices(0), np.random.default_rng(0))
    assert images.shape[1:] == (4, 64, 64) and masks.shape[1:] == (1, 64, 64)
    assert -1 <= float(images[:, 3].min()) and float(images[:, 3].max()) <= 1
    assert float(masks.amax(dim=(1, 2, 3)).min()) > 0.5   # every square holds the object
    assert float((thin * (masks <= 0.5)).sum()) == 0 and float(thin.sum()) > 0
    with pytest.raises(ValueError, match="--teacher"):
        Trainer(config(tiny_data, tmp_path / "bad", **{**refine, "teacher": None}))
    with pytest.raises(ValueError, match="not a foreground network"):
        Trainer(config(tiny_data, tmp_path / "bad2", **{**refine, "teacher": str(runs / "img")}))


def test_a_refined_mask_replaces_the_first_in_the_objects_square():
    from model.image.mask import MaskSpec, crop_input, refined_mask

    spec = MaskSpec(size=32, crop_size=64, crop_margin=0.1)
    rgb = np.zeros((120, 200, 3), np.uint8)
    first = np.zeros((120, 200), np.float32)
    first[40:80, 60:100] = 1                              # the first look: a square body, no rod
    x = crop_input(rgb, first, (36, 84, 56, 104), spec)
    assert x.shape == (4, 64, 64) and x[3].max() == 1 and x[3].min() == -1

    def refine(crop):                                     # a refinement that finds a rod right of the body
        p = (crop[3] > 0).astype(np.float32)
        p[28:34, 50:64] = 1
        return p

    out = refined_mask(rgb, first, refine, spec)
    assert out.shape == first.shape and out[40:80, 60:100].min() > 0.5
    assert out[60, 100:104].min() > 0.5                   # the rod, to the square's edge
    assert out[:, :50].max() == 0 and out[:30].max() == 0  # nothing outside the square


def test_the_refinement_network_goes_into_the_bundle_and_the_framing_uses_it(tiny_data, runs, tmp_path):
    """export --foreground FG --refine R: the bundle holds foreground_refine (4 input channels), its
    mask settings the refinement's crop side; onnxruntime gives torch's probabilities; the framing
    of a photo looks again at the object's square through it; --verify runs it."""
    from export.__main__ import main as export_main
    from export.bundle import BundleError, load_bundle
    from export.exporter import export
    from export.runtime import Runtime
    from model.checkpoint import load_model
    from model.image.frame import ImageSpec, frame_object
    from model.image.mask import crop_input

    refine = dict(task="refine", arch="unet-lite", encoder_width=4, image_size=64, teacher=str(runs / "fg"))
    Trainer(config(tiny_data, tmp_path / "r", iters=2, val_every=2, ckpt_every=2, **refine)).run()
    meta = export(runs / "img", tmp_path / "b", foreground=runs / "fg", refine=tmp_path / "r",
                  foreground_precision="float32")
    assert meta["graphs"]["foreground_refine"]["inputs"]["image"]["shape"] == ["batch", 4, 64, 64]
    assert meta["export"]["self_check"]["refine_relative_error"] <= RELATIVE_TOLERANCE
    bundle = load_bundle(tmp_path / "b")
    spec = bundle.mask_spec()
    assert spec.crop_size == 64 and spec.size == 32
    rt = Runtime(bundle, threads=1)
    rgb = np.random.default_rng(0).integers(0, 256, (90, 120, 3), dtype=np.uint8)
    first = np.zeros((90, 120), np.float32)
    first[30:60, 40:90] = 1
    x = crop_input(rgb, first, (20, 70, 30, 100), spec)
    with torch.no_grad():
        want = torch.sigmoid(load_model(tmp_path / "r").model.net(torch.from_numpy(x[None]))).numpy()[0, 0]
    assert np.abs(rt.refine(x) - want).max() < 1e-4
    looks = []
    framed = frame_object(rgb, ImageSpec(size=32), lambda im: first[::3, ::3] if im.shape[:2] == (90, 120) else
                          np.ones((32, 32), np.float32), remove_background="true", mask_spec=spec,
                          refine=lambda crop: looks.append(crop.shape) or rt.refine(crop))
    assert looks == [(4, 64, 64)] and framed.mask_source == "network"
    assert export_main(["--verify", str(tmp_path / "b")]) == 0
    # the photo evaluation of the foreground network through this bundle looks again through it
    import dataclasses

    from model.data.photos import photo_split_view
    from model.train.tasks import TASKS
    from research.evaluate import EvalOptions, evaluate
    from research.masks import photo_masks, thin_recall
    res = evaluate(str(runs / "fg"), str(tiny_data), EvalOptions("train", limit=3, bundle=str(tmp_path / "b")))
    cfg = dataclasses.replace(load_model(runs / "fg").config, data=str(tiny_data))
    photos = [photo_split_view(s.images, s.shape_id) for s in TASKS["foreground"].dataset(cfg, "train", 0, limit=3).samples]
    served = Runtime(bundle)                              # as the evaluation opens it (its thread count)
    recalls = [thin_recall(m, p) for m, p in zip(photo_masks(photos, served.segment, spec, served.refine), photos)]
    # a pixel at 0.5 may flip between onnxruntime's kernels: a tolerance, far below the refinement's effect
    assert res["refined"] and [r["thin_recall"] for r in res["per_shape"]] == pytest.approx(recalls, abs=0.02)
    assert res["thin_recall_mean"] == pytest.approx(np.mean(recalls), abs=0.02)
    plain = evaluate(str(runs / "fg"), str(tiny_data), EvalOptions("train", limit=3))
    assert not plain["refined"] and all(0 <= r["thin_recall"] <= 1 for r in plain["per_shape"])
    with pytest.raises(BundleError, match="--refine goes with --foreground"):
        export(runs / "img", tmp_path / "c", refine=tmp_path / "r")
    with pytest.raises(BundleError, match="not a refinement network"):
        export(runs / "img", tmp_path / "c", foreground=runs / "fg", refine=runs / "fg")
