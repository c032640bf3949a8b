"""The shipped checkpoints under models/checkpoints load, match their provenance, and run."""

import json
from pathlib import Path

import numpy as np
import pytest
import torch

from model.checkpoint import load_model
from model.files import sha256_file

CHECKPOINTS = Path(__file__).resolve().parents[2] / "models" / "checkpoints"
BUNDLES = CHECKPOINTS.parent / "bundles"
SHIPPED = ["image-to-shape", "completion", "classify"]
CHECKPOINTED = [*SHIPPED, "foreground"]           # the foreground network ships inside the image bundle


@pytest.mark.parametrize("name", CHECKPOINTED)
def test_shipped_checkpoint_matches_its_json_and_works(name):
    folder = CHECKPOINTS / name
    meta = json.loads((folder / "model.json").read_text())
    weights = folder / meta["weights"]
    assert sha256_file(weights) == meta["weights_sha256"]
    for key in ("command", "data", "evaluation", "config"):
        assert meta[key]
    # trained by the recipe's command, or by hand and packaged with --run (its config and steps then stand)
    assert meta["train_command"] or (" --run " in meta["command"] and meta["steps"] > 0)
    assert len(meta["data"]["manifest_sha256"]) == 64
    loaded = load_model(folder)             # checks the weights' sha256 again; needs no teacher run
    assert sum(p.numel() for p in loaded.model.parameters()) <= meta["parameters"]
    CHECKS[meta["task"]](loaded, meta)


def _decodes_a_photo(loaded, meta):
    """A white square on a grey photo: a finite latent and a non-empty octree."""
    from model.decode import decode
    from model.image.frame import prepare_image
    from model.networks import TorchSteps
    from model.octree.batch import split_octree

    model, cfg = loaded.model, loaded.config
    x = torch.from_numpy(prepare_image(_photo(), cfg.image_spec())[None])
    with torch.no_grad():
        latent = model.encoder(x)
    assert torch.isfinite(latent).all()
    tree = split_octree(decode(TorchSteps(model.decoder), latent.numpy()))[0]
    assert sum(tree.leaves_per_depth()) > 0
    assert meta["evaluation"]["chamfer_x1e3_category_mean"] > 0


def _completes_a_scan_with_holes(loaded, meta):
    """An unseen car scanned from 3 views with holes, in arbitrary units and position: the
    completion covers the missing part far better than the scan itself does.  (Scans that miss
    a whole side, so that the shape extends far beyond the scan's bounding box, are out of the
    model's reach: its frame is the scan's box enlarged 1.1x.)"""
    from model.data import generate, partial_from_scan, scan_detailed
    from model.decode import decode
    from model.networks import TorchSteps
    from model.octree import scan_frame, scan_octree, validate
    from model.octree.batch import split_octree
    from model.octree.metrics import missing_distance, sample_patches

    full = scan_detailed(generate("car", 9001), resolution=160, rng=np.random.default_rng(0))
    pts, nrm, _ = partial_from_scan(full, np.random.default_rng(1), n_views=(3, 3), holes_per_view=(2, 2))
    move = lambda p: p * 3.0 + [10.0, -4.0, 2.0]              # noqa: E731  the user's units and position
    cloud = validate(move(pts), nrm)
    with torch.no_grad():
        latent, guide = loaded.model.encode_octree(scan_octree(cloud, loaded.config.depth))
    tree = split_octree(decode(TorchSteps(loaded.model.decoder), latent.numpy(), guide=guide))[0]
    tree.normalizations = [scan_frame(cloud.points)]
    out = sample_patches(tree, resolution=128, seed=0)        # world coordinates
    truth, gap = move(full.points), 3.0 * 2 / 64              # two finest voxels
    assert missing_distance(truth, cloud.points, out, gap) < 0.25 * missing_distance(truth, cloud.points,
                                                                                       cloud.points, gap)
    assert meta["evaluation"]["chamfer_x1e3_category_mean"] > 0


def _classifies_unseen_shapes(loaded, meta):
    """One unseen shape of every category: most are recognised."""
    from model.data import generate, scan
    from model.nn.tensors import OctreeTensors
    from model.octree import build_octree
    from model.octree.batch import merge_octrees

    cfg = loaded.config
    trees = [build_octree(scan(generate(c, 9001), resolution=160), cfg.depth) for c in cfg.categories]
    with torch.no_grad():
        pred = loaded.model.logits(OctreeTensors.from_octree(merge_octrees(trees))).argmax(1).numpy()
    assert (pred == np.arange(len(cfg.categories))).mean() >= 0.75
    assert 0 < meta["evaluation"]["voted_accuracy"] <= 1


def _photo_of_an_unseen_chair(seed: int = 0):
    """A chair the network never saw, rendered and composited on a held-out photograph."""
    from model.data import generate
    from model.data.photos import PhotoStyle, photo_composite
    from model.data.render import render

    rgba, _ = render(generate("chair", 9001), 40.0, 25.0, 2.8, size=137)
    return photo_composite(rgba, np.random.default_rng(seed), "test", PhotoStyle(scale=(0.5, 0.8), real=1.0))


def _finds_the_object_in_a_photo(loaded, meta):
    """An unseen chair on held-out photographs: the mask finds it (IoU with the exact mask)."""
    from model.image.mask import object_mask
    from model.networks.foreground import torch_segment
    from model.train.tasks import TASKS

    spec = TASKS["foreground"].spec(loaded.config)
    segment = torch_segment(loaded.model.net, spec)
    ious = []
    for seed in range(4):
        photo = _photo_of_an_unseen_chair(seed)
        ours, truth = object_mask(photo.rgb, segment, spec) > 0.5, photo.mask > 0.5
        ious.append((ours & truth).sum() / (ours | truth).sum())
    assert np.median(ious) >= 0.7, ious
    assert 0 < meta["evaluation"]["mask_iou_category_mean"] <= 1


CHECKS = {"image-to-shape": _decodes_a_photo, "completion": _completes_a_scan_with_holes,
          "classify": _classifies_unseen_shapes, "foreground": _finds_the_object_in_a_photo}


def test_the_image_bundle_carries_the_shipped_foreground_network():
    """The image bundle's foreground graph is the foreground checkpoint's export (stored in int8):
    onnxruntime gives torch's mask on a photo, and the service's framing finds the chair in it."""
    from export.bundle import load_bundle
    from export.exporter import FOREGROUND_INT8_AGREEMENT
    from export.runtime import Runtime
    from model.image.frame import frame_object
    from model.image.mask import mask_input

    bundle = load_bundle(BUNDLES / "image-to-shape")
    meta = json.loads((CHECKPOINTS / "foreground" / "model.json").read_text())
    assert bundle.meta["provenance"]["foreground"]["weights_sha256"] == meta["weights_sha256"]
    runtime = Runtime(bundle, threads=1)
    photo = _photo_of_an_unseen_chair()
    x = mask_input(photo.rgb, bundle.mask_spec())[None]
    with torch.no_grad():
        want = load_model(CHECKPOINTS / "foreground").model.net(torch.from_numpy(x)).numpy()
    got = runtime.run("foreground", {"image": x})[0]
    assert bundle.meta["export"]["foreground_precision"] == "int8"
    assert np.mean((got > 0) == (want > 0)) >= FOREGROUND_INT8_AGREEMENT
    assert np.abs(got - want).max() < 0.1 * np.abs(want).max()          # int8 steps, not another network
    framed = frame_object(photo.rgb, bundle.image_spec(), runtime.segment, mask_spec=bundle.mask_spec())
    assert framed.mask_source == "network"
    t, l, b, r = framed.box
    tt, tl, tb, tr = photo.box
    assert max(abs(t - tt), abs(l - tl), abs(b - tb), abs(r - tr)) <= 0.1 * max(tb - tt, tr - tl)


def _photo() -> np.ndarray:
    """A white square on a grey photo."""
    img = np.full((90, 120, 3), 128, np.uint8)
    img[20:70, 30:90] = 240
    return img


@pytest.mark.parametrize("name", SHIPPED)
def test_shipped_bundle_is_the_checkpoint_s_export_and_matches_it(name):
    """The committed bundle verifies, records its checkpoint's weights, and onnxruntime gives
    torch's latent and, step by step on the same octants, its decoder outputs (or probabilities)
    on a real input, within the cross-CPU tolerance (export.parity)."""
    from export.bundle import load_bundle
    from export.parity import RELATIVE_TOLERANCE, decoder_parity, relative_error
    from export.runtime import Runtime
    from model.networks import TorchSteps
    from model.nn.tensors import OctreeTensors

    bundle = load_bundle(BUNDLES / name)
    meta = json.loads((CHECKPOINTS / name / "model.json").read_text())
    assert bundle.meta["provenance"]["weights_sha256"] == meta["weights_sha256"]
    assert bundle.meta["evaluation"] == meta["evaluation"]
    model = load_model(CHECKPOINTS / name).model
    runtime = Runtime(bundle, threads=1)
    guide = None
    if bundle.task == "image-to-shape":
        from model.image.frame import prepare_image
        x = prepare_image(_photo(), bundle.image_spec())[None]
        latent, xt = runtime.encode_image(x), torch.from_numpy(x)
    else:
        from model.data import generate, scan
        from model.octree import build_octree, scan_octree, validate
        cloud = validate(*scan(generate("chair", 9002), resolution=96))
        o = bundle.octree
        tree = (scan_octree(cloud, o.depth, adaptive=o.adaptive) if bundle.task == "completion"
                else build_octree(cloud, o.depth, adaptive=o.adaptive))
        (latent, guide), xt = runtime.encode_scan(tree), OctreeTensors.from_octree(tree)
    guide_t = None
    with torch.no_grad():
        latent_t = model.encoder(xt).numpy()
        assert relative_error(latent_t, latent) <= RELATIVE_TOLERANCE
        if bundle.task == "classify":
            want = torch.softmax(model.head(torch.from_numpy(latent)), 1).numpy()
            assert relative_error(want, runtime.classify(latent)) <= RELATIVE_TOLERANCE
            return
        if guide is not None:            # a guided decoder: the encoder's features of the scan, too
            guide_t = model.encode_octree(tree)[1]
            assert all(relative_error(guide_t.features[d].numpy(), guide.features[d]) <= RELATIVE_TOLERANCE
                       for d in guide.features)
    dec = model.decoder
    report, octree = decoder_parity(TorchSteps(dec), runtime.steps(), latent_t, dec.full_depth, dec.adaptive_depth,
                                    other_latent=latent, guides=None if guide is None else (guide_t, guide))
    assert report.ok, report.summary()
    assert sum(octree.leaves_per_depth()) > 100


def test_models_folder_fits_its_budget():
    total = sum(f.stat().st_size for f in CHECKPOINTS.parent.rglob("*") if f.is_file())
    assert total <= 60 * 1024 * 1024


def test_shipped_provenance_names_no_machines_paths():
    """model.json of every shipped checkpoint and bundle: commands and sources name paths relative
    to the repository, never a folder of the machine they were made on."""
    def strings(value):
        if isinstance(value, dict):
            for v in value.values():
                yield from strings(v)
        elif isinstance(value, list):
            for v in value:
                yield from strings(v)
        elif isinstance(value, str):
            yield value

    files = sorted(CHECKPOINTS.parent.glob("*/*/model.json"))
    assert len(files) == len(CHECKPOINTED) + len(SHIPPED)
    for f in files:
        absolute = [token for s in strings(json.loads(f.read_text())) for token in s.split()
                    if token.startswith("/") and "/" in token[1:]]
        assert not absolute, (f, absolute)
