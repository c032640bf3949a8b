"""Shape completion and classification as training tasks: their data, resume, evaluation."""

import json

import numpy as np
import pytest
import torch

from model.data.dataset import load_record
from model.octree import build_octree, scan_frame, scan_octree, validate
from model.octree.geometry import axis_rotation
from model.train.loop import Trainer

from .test_train import config, trains_and_resumes_identically


def _same_octree(a, b) -> bool:
    return all(np.array_equal(x.key, y.key) and np.array_equal(x.label, y.label)
               and np.allclose(x.plane, y.plane, atol=1e-6) for x, y in zip(a.levels, b.levels))


def test_completion_inputs_are_the_services_octrees_with_and_without_normals(scan_data):
    from model.train.completion import CompletionSet

    data = CompletionSet(scan_data, "train", limit=3)
    manifest = json.loads((scan_data / "manifest.json").read_text())
    row = [r for r in manifest["records"] if r["split"] == "train"][1]
    rec = load_record(scan_data / row["path"])
    for j, variant in enumerate(data.variants[1]):
        pts, nrm = rec.partial(j)
        frame = scan_frame(np.asarray(pts, np.float64))
        assert _same_octree(variant.inputs["given"], scan_octree(validate(pts, nrm), 5))
        assert _same_octree(variant.inputs["estimated"], scan_octree(validate(pts, None), 5))
        assert not _same_octree(variant.inputs["given"], variant.inputs["estimated"])
        # the target: the complete scan, in the same frame as the input (the partial's enlarged cube)
        assert _same_octree(variant.target, build_octree((rec["points"], rec["normals"]), 5, normalization=frame))
        for tree in (variant.target, variant.inputs["given"]):
            n = tree.normalizations[0]
            assert np.allclose(n.center, frame.center) and n.scale == pytest.approx(frame.scale)
    # the frame holds the partial with its margin: its longest edge fills 0.96 / 1.1 of the cube
    cube = frame.to_cube(pts)
    assert (cube.max(0) - cube.min(0)).max() == pytest.approx(0.96 / 1.1)


def test_build_octree_in_a_given_frame_drops_points_outside_it():
    rng = np.random.default_rng(0)
    p = rng.normal(size=(3000, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    half = scan_frame(p[p[:, 0] < 0])                    # the frame of the left half only
    tree = build_octree((p, p), 5, normalization=half)
    inside = ((half.to_cube(p) >= 0) & (half.to_cube(p) < 1)).all(1)
    assert 0 < inside.sum() < len(p) and tree.levels[0].npoints[0] == inside.sum()
    from model.octree import OctreeInputError
    far = scan_frame(p + 10)
    with pytest.raises(OctreeInputError, match="inside the given frame"):
        build_octree((p, p), 5, normalization=far)


def test_completion_training_resumes_and_evaluates_against_the_input_floor(scan_data, tmp_path):
    from research.evaluate import main as evaluate_main
    from research.results_table import main as table_main

    straight, summary = trains_and_resumes_identically(scan_data, tmp_path, task="completion",
                                                       structure_loss="balanced")
    assert np.isfinite(summary["train"]["total"])
    # training draws scans and normal modes at random: two steps see different inputs
    rng = np.random.default_rng(0)
    idx = np.arange(4)
    drawn = {tuple(int(x) for x in straight.train_set.pairs(idx, rng)[0].nodes_per_depth()) for _ in range(6)}
    assert len(drawn) > 1

    for normals in ("given", "estimated"):
        out = tmp_path / f"{normals}.json"
        assert evaluate_main([str(tmp_path / "a"), "--data", str(scan_data), "--split", "train", "--limit", "4",
                              "--resolution", "32", "--normals", normals, "--out", str(out)]) == 0
        res = json.loads(out.read_text())
        assert res["task"] == "completion" and res["normals"] == normals and res["shapes"] == 4
        shares = [r["watertight_crossing_share"] for r in res["per_shape"]]     # the closed surface's crossings
        assert all(0 <= x <= 1 for x in shares) and res["watertight_crossing"] == sum(x > 0 for x in shares)
        floor = [r["input_chamfer_x1e3"] for r in res["per_shape"]]
        assert all(0 < f < 50 for f in floor)                 # partial scans of the truth: close, not equal
        # the missing part lies beyond 1/32 of the cube from the scan, by definition, at every depth
        assert all(r["input_missing_x1e3"] is None or r["input_missing_x1e3"] > (1 / 32) ** 2 * 1e3
                   for r in res["per_shape"])
        assert res["input_chamfer_x1e3_category_mean"] == pytest.approx(
            np.mean([np.mean([r["input_chamfer_x1e3"] for r in res["per_shape"] if r["category"] == c])
                     for c in {r["category"] for r in res["per_shape"]}]))
    assert table_main([str(tmp_path / "given.json"), str(tmp_path / "estimated.json")]) == 0
    # keep_scan (the scan's own patches where it saw the shape: tests/octree/test_fuse.py) changes
    # the outputs, not the inputs
    kept = tmp_path / "kept.json"
    assert evaluate_main([str(tmp_path / "a"), "--data", str(scan_data), "--split", "train", "--limit", "4",
                          "--resolution", "32", "--keep-scan", "--out", str(kept)]) == 0
    kept, plain = json.loads(kept.read_text()), json.loads((tmp_path / "given.json").read_text())
    assert kept["keep_scan"] is True and plain["keep_scan"] is False
    assert all(a["chamfer_x1e3"] != b["chamfer_x1e3"] for a, b in zip(kept["per_shape"], plain["per_shape"]))

    # the keep_scan bias: chosen on a split, recorded with the run, used by evaluation (carried by
    # export: the guided test below, which exports anyway)
    from research.calibrate import keep_scan_candidates
    from research.calibrate import main as calibrate_main

    assert calibrate_main([str(tmp_path / "a"), "--data", str(scan_data), "--split", "train", "--keep-scan",
                           "--limit", "2", "--resolution", "32"]) == 0
    report = json.loads((tmp_path / "a" / "keep_scan.json").read_text())
    scores = [c["chamfer_x1e3_category_mean"] for c in report["candidates"]]
    assert len(scores) == len(keep_scan_candidates(5)) and report["candidates"][int(np.argmin(scores))]["tied_with_lowest"]
    assert report["shapes"] == 2 and report["resolution"] == 32
    row = min((c for c in report["candidates"] if c["tied_with_lowest"]), key=lambda c: c["missing_x1e3_category_mean"])
    chosen = row["empty_bias"]
    assert report["empty_bias"] == chosen and report["chamfer_x1e3_category_mean"] == row["chamfer_x1e3_category_mean"]
    assert report["missing_x1e3_category_mean"] == row["missing_x1e3_category_mean"]
    again = tmp_path / "again.json"
    assert evaluate_main([str(tmp_path / "a"), "--data", str(scan_data), "--split", "train", "--limit", "4",
                          "--resolution", "32", "--keep-scan", "--out", str(again)]) == 0
    assert json.loads(again.read_text())["keep_scan_empty_bias"] == chosen
    assert [r["input_chamfer_x1e3"] for r in kept["per_shape"]] == [r["input_chamfer_x1e3"] for r in plain["per_shape"]]
    # on a subset every category is in: the first shape of each (the split's rows are by category)
    assert calibrate_main([str(tmp_path / "a"), "--data", str(scan_data), "--split", "train", "--keep-scan",
                           "--per-category", "1", "--resolution", "32"]) == 0
    subset = json.loads((tmp_path / "a" / "keep_scan.json").read_text())
    manifest = json.loads((scan_data / "manifest.json").read_text())
    categories = {r["category"] for r in manifest["records"] if r["split"] == "train"}
    assert subset["shapes"] == len(categories) == 2 and subset["per_category"] == 1
    assert calibrate_main([str(tmp_path / "a"), "--data", str(scan_data), "--per-category", "1", "--out",
                           str(tmp_path / "x")]) == 2
    assert not (tmp_path / "x").exists()


def test_completion_cache_is_rebuilt_when_stale_or_damaged(scan_data):
    from model.train.completion import CompletionSet

    first = CompletionSet(scan_data, "train", limit=1)
    cached = sorted((scan_data / "cache").glob("completion-adaptive-*/records/*/*.npz"))
    target = [c for c in cached if c.stem == first.samples[0].shape_id][0]
    target.write_bytes(b"garbage")
    again = CompletionSet(scan_data, "train", limit=1)
    assert _same_octree(again.samples[0].octree, first.samples[0].octree)
    with np.load(target) as f:
        assert str(f["record_sha256"]) != ""


def test_the_missing_part_is_the_same_part_of_a_shape_for_models_of_every_depth():
    """Truth points 1.5/32 of the cube beyond the scan are missing (two voxels at depth 6), those
    0.5/32 beyond are seen, whatever the depth: a depth-7 model is measured on the shipped one's part."""
    from types import SimpleNamespace

    from research.measures import MISSING_GAP, missing_rows

    assert MISSING_GAP == 2 / 64
    scan = np.stack([np.linspace(-1, 1, 401), np.zeros(401), np.zeros(401)], 1)
    truth = np.concatenate([scan, scan + [0, 0.5 / 32, 0], scan + [0, 1.5 / 32, 0]])
    rows = missing_rows(SimpleNamespace(points=truth, partial=scan), scan)
    assert rows["input_missing_x1e3"] == pytest.approx((1.5 / 32) ** 2 * 1e3, rel=1e-3)   # only the far line
    assert rows["missing_x1e3"] == rows["input_missing_x1e3"]


def _damage_after_scans(path) -> None:
    """Flip bytes inside every array of a cache file but its checksum and scan count."""
    import struct
    import zipfile

    data = bytearray(path.read_bytes())
    with zipfile.ZipFile(path) as z:
        members = [i for i in z.infolist() if i.filename not in ("record_sha256.npy", "scans.npy")]
    spans = []
    for i in members:                 # the data follow the local header, its name and its extra field
        name, extra = struct.unpack("<HH", data[i.header_offset + 26:i.header_offset + 30])
        spans.append((i.header_offset + 30 + name + extra, i.compress_size))
    for start, size in spans:
        for k in range(start + size // 4, start + size // 4 + min(8, size // 2)):
            data[k] ^= 0xFF
    path.write_bytes(bytes(data))


def test_a_streamed_completion_set_gives_the_same_samples_and_batches(scan_data):
    from model.train.completion import CompletionSet

    held = CompletionSet(scan_data, "train", points=64)
    streamed = CompletionSet(scan_data, "train", points=64, stream=2)
    assert len(streamed) == len(held) >= 3 and streamed.depth == held.depth
    assert isinstance(held.samples, list) and not isinstance(streamed.samples, list)
    for a, b in zip(held.samples, streamed.samples):
        assert (a.category, a.shape_id) == (b.category, b.shape_id)
        assert np.array_equal(a.points, b.points) and np.array_equal(a.partial, b.partial)
        assert _same_octree(a.octree, b.octree) and a.truth_frame.scale == b.truth_frame.scale
    order = [2, 0, 1, 2]
    x, y = held.pairs(order, np.random.default_rng(5)), streamed.pairs(order, np.random.default_rng(5))
    assert all(_same_octree(a, b) for a, b in zip(x, y))
    assert _same_octree(held.scan(1), streamed.scan(1))
    assert streamed.samples[-1].shape_id == held.samples[-1].shape_id and len(streamed.samples[:2]) == 2
    with pytest.raises(IndexError):
        streamed.samples[len(held)]
    # training reads the drawn octrees from the cache alone (no shape's variants are built); a
    # cache file damaged after the set was built is rebuilt once, and the draw is the same
    from model.train.data import LazySequence

    damaged = sorted((scan_data / "cache").glob("completion-adaptive-*/records/*/*.npz"))
    damaged = [c for c in damaged if c.stem == held.samples[2].shape_id][0]
    again = CompletionSet(scan_data, "train", points=64, stream=2)
    built, variants = [], again.variants
    again.variants = LazySequence(len(variants), lambda i: built.append(i) or variants[i])
    assert all(_same_octree(a, b) for a, b in zip(x, again.pairs(order, np.random.default_rng(5))))
    assert built == []
    _damage_after_scans(damaged)     # readable up to the draw, not after it
    rng, held_rng = np.random.default_rng(5), np.random.default_rng(5)
    z = again.pairs(order, rng)
    held.pairs(order, held_rng)
    assert all(_same_octree(a, b) for a, b in zip(x, z))
    assert rng.bit_generator.state == held_rng.bit_generator.state      # nothing drawn twice
    assert built == [2]              # shape 2 read whole once, its file rebuilt: its second draw is fast


def test_a_streamed_record_set_gives_the_same_samples_image_batches_and_training(tiny_data, tmp_path):
    import shutil

    from model.image.frame import ImageSpec
    from model.train.data import RecordSet
    from model.train.images import image_batch

    held = RecordSet(tiny_data, "train", images=True, seed=3, points=64)
    streamed = RecordSet(tiny_data, "train", images=True, seed=3, points=64, stream=2)
    assert len(streamed) == len(held) >= 3 and streamed.depth == held.depth == 5
    assert isinstance(held.samples, list) and not isinstance(streamed.samples, list)
    for a, b in zip(held.samples, streamed.samples):
        assert (a.category, a.shape_id) == (b.category, b.shape_id) and np.array_equal(a.points, b.points)
        assert _same_octree(a.octree, b.octree) and np.array_equal(a.images, b.images)
    order = [2, 0, 1, 2]
    for seed in range(4):             # random views, backgrounds drawn from the other samples, photos
        x = image_batch([held.samples[i] for i in order], ImageSpec(size=32), np.random.default_rng(seed), 1.0,
                        held.samples, photo_share=0.3)
        y = image_batch([streamed.samples[i] for i in order], ImageSpec(size=32), np.random.default_rng(seed),
                        1.0, streamed.samples, photo_share=0.3)
        assert np.array_equal(x, y)

    # renders only (the foreground network's set): the same renders, no octree or points read
    for stream in (0, 2):
        renders = RecordSet(tiny_data, "train", None, images=True, seed=3, stream=stream)
        for a, b in zip(held.samples, renders.samples):
            assert (a.category, a.shape_id) == (b.category, b.shape_id) and np.array_equal(a.images, b.images)
            assert b.octree is None and b.points.shape == (0, 3)
    with pytest.raises(ValueError, match="images=True"):
        RecordSet(tiny_data, "train", None)

    # the same training, step for step (the image task's inputs come through the stream)
    kw = dict(task="image", arch="aocnn", encoder="lenet", encoder_width=4, image_size=32, iters=3, val_every=3)
    a = Trainer(config(tiny_data, tmp_path / "held", **kw))
    b = Trainer(config(tiny_data, tmp_path / "streamed", stream=2, **kw))
    sa, sb = a.run(), b.run()
    assert sa["val"]["total"] == sb["val"]["total"]
    wa, wb = a.model.state_dict(), b.model.state_dict()
    assert all(torch.equal(wa[k], wb[k]) for k in wa)

    # a damaged record is named when the set is built, not at some later step
    broken = tmp_path / "broken"
    shutil.copytree(tiny_data, broken)
    row = json.loads((broken / "manifest.json").read_text())["records"][0]
    (broken / row["path"]).write_bytes(b"not a record")
    with pytest.raises(ValueError, match="missing or damaged"):
        RecordSet(broken, row["split"], stream=2)
    with pytest.raises(ValueError, match="stream must be 0"):
        RecordSet(tiny_data, "train", stream=-1)
    with pytest.raises(ValueError, match="stream must be 0"):
        Trainer(config(tiny_data, tmp_path / "cls", task="classify", stream=2))


def test_classify_trains_on_rotations_resumes_and_votes(tiny_data, tmp_path, capsys):
    from model.train.classify import ROTATIONS
    from research.evaluate import main as evaluate_main

    straight, summary = trains_and_resumes_identically(tiny_data, tmp_path, task="classify")
    assert straight.cfg.categories == ["airplane", "chair", "table"]      # the dataset's, fixed in the config
    assert 0 <= summary["val"]["accuracy"] <= 1 and np.isfinite(summary["val"]["cross_entropy"])

    # rotation k is the shape turned by k * 30 degrees about the up axis, normalised anew
    data = straight.train_set
    rec = load_record(tiny_data / json.loads((tiny_data / "manifest.json").read_text())["records"][0]["path"])
    assert data.samples[0].shape_id == str(rec["shape_id"])
    r = axis_rotation(2 * np.pi * 3 / ROTATIONS, "y")
    want = build_octree((rec["points"] @ r.T, rec["normals"] @ r.T), 5, neighbors=False)
    rotated = data.rotations[0]
    assert _same_octree(rotated[3], want)
    assert not _same_octree(rotated[0], rotated[3])

    out = tmp_path / "cls.json"
    assert evaluate_main([str(tmp_path / "a"), "--data", str(tiny_data), "--split", "val", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert len(res["accuracy_per_rotation"]) == ROTATIONS and res["accuracy_per_rotation"][0] == res["accuracy"]
    assert np.sum(res["confusion"]) == res["shapes"]
    assert res["voted_accuracy"] == pytest.approx(np.trace(res["confusion"]) / res["shapes"])
    assert evaluate_main([str(tmp_path / "a"), "--data", str(tiny_data), "--keep-scan", "--out", str(out)]) == 2
    assert "--keep-scan goes with a completion model" in capsys.readouterr().err

    # --bundle runs the exported classifier in onnxruntime and says so; a bundle of another task is refused
    from export.exporter import export
    export(tmp_path / "a", tmp_path / "bundle")
    via = tmp_path / "cls-bundle.json"
    assert evaluate_main([str(tmp_path / "a"), "--data", str(tiny_data), "--split", "val", "--out", str(via),
                          "--bundle", str(tmp_path / "bundle")]) == 0
    onnx = json.loads(via.read_text())
    assert onnx["bundle"] == str(tmp_path / "bundle") and res["bundle"] is None
    assert [r["voted"] for r in onnx["per_shape"]] == [r["voted"] for r in res["per_shape"]]
    assert onnx["accuracy_per_rotation"] == res["accuracy_per_rotation"]


@pytest.mark.parametrize("task, extra, needle", [
    ("completion", ["--arch", "psg"], "invalid choice"),
    ("completion", ["--workers", "0"], "--workers must be at least 1"),
    ("classify", ["--arch", "ocnn-patch"], "invalid choice"),
    ("classify", ["--categories", "chair"], "at least 2 categories"),
])
def test_task_commands_reject_bad_settings_in_one_line(tiny_data, tmp_path, capsys, task, extra, needle):
    from model.train.__main__ import main

    argv = [task, "--data", str(tiny_data), "--depth", "5", "--out", str(tmp_path / "r"), "--iters", "1", *extra]
    try:
        code = main(argv)
    except SystemExit as exc:           # argparse's own refusal
        code = exc.code
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and needle in err[-1]


def test_completion_needs_a_dataset_with_partial_scans(tiny_data, tmp_path):
    with pytest.raises(ValueError, match="no partial scans"):
        Trainer(config(tiny_data, tmp_path / "r", task="completion"))


def test_degradation_table_pairs_settings_and_reads_fewer_views_as_worse_input(scan_data, tmp_path, monkeypatch):
    import research.degrade as degrade
    from research.degrade import PartialSettings, main

    # a setting whose holes remove every point: left out of its rows and counted, not a crash
    SETTINGS = (*degrade.SETTINGS, PartialSettings("no points left", views=(1, 1), holes=(9, 9), radius=(2.0, 2.0)))
    monkeypatch.setattr(degrade, "SETTINGS", SETTINGS)
    Trainer(config(scan_data, tmp_path / "run", task="completion", iters=2)).run()
    out = tmp_path / "deg.json"
    assert main([str(tmp_path / "run"), "--data", str(scan_data), "--limit-per-category", "1",
                 "--split", "train", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["shapes"] == 2 and len(res["settings"]) == len(SETTINGS)
    floor = {k: v["rows"]["input"]["chamfer_x1e3_category_mean"] for k, v in res["settings"].items()}
    assert floor["1 view"] > floor[SETTINGS[0].name]
    assert floor["noise 0.02"] > floor["noise 0.01"]
    empty = res["settings"]["no points left"]["rows"]["input"]
    assert empty["too_few_points"] == 2 and empty["chamfer_x1e3_category_mean"] is None
    missing = {k: v["rows"]["input"]["missing_x1e3_category_mean"] for k, v in res["settings"].items()}
    assert missing["1 view"] > missing[SETTINGS[0].name] > (2 / 32) ** 2 * 1e3     # at least the gap, squared


def test_guided_completion_reads_the_scans_features_trains_resumes_and_exports(scan_data, tmp_path):
    """Output-guided skip connections: the decoder's octants that the scan also has get the
    encoder's features; training resumes identically; calibration, evaluation and export follow."""
    from export.bundle import load_bundle
    from export.exporter import export
    from model.decode import matched_rows
    from model.nn.tensors import OctreeTensors
    from research.calibrate import main as calibrate_main
    from research.evaluate import main as evaluate_main

    straight, summary = trains_and_resumes_identically(scan_data, tmp_path, task="completion",
                                                       structure_loss="balanced", skips=True)
    assert np.isfinite(summary["train"]["total"]) and straight.model.guided
    # the skips add no weights: resuming without --skips would silently train another network
    with pytest.raises(ValueError, match="skips=True"):
        Trainer(config(scan_data, tmp_path / "a", task="completion", structure_loss="balanced", iters=6,
                       ckpt_every=3, val_every=3))
    source, target = straight.train_set.pairs(np.arange(3))
    rows = matched_rows(source, target)
    for d, r in rows.items():             # a row points at the scan's octant with the same key, or past the end
        found = r < len(source.levels[d])
        assert np.array_equal(source.levels[d].key[r[found]], target.levels[d].key[found])
        assert not np.isin(target.levels[d].key[~found], source.levels[d].key).any()
    assert rows[2].tolist() == list(range(3 * 64))              # the full depth: every octant shared
    assert 0 < np.mean(rows[5] < len(source.levels[5])) < 1     # the finest: the scan saw part of the shape
    model = straight.model.eval()
    with pytest.raises(ValueError, match="rows"):
        model(OctreeTensors.from_octree(source), None, OctreeTensors.from_octree(target))
    # the skip connections carry the scan: other scans' features give other predictions
    with torch.no_grad():
        latent, features = model.encoder.features(OctreeTensors.from_octree(source))
        t = OctreeTensors.from_octree(target)
        own = model.decoder(latent, t, {d: (features[d], torch.from_numpy(r)) for d, r in rows.items()})
        none = model.decoder(latent, t, {d: (features[d], torch.full_like(torch.from_numpy(r), len(features[d])))
                                         for d, r in rows.items()})
    assert all(float((a[0] - b[0]).abs().max()) > 1e-4 for a, b in zip(own, none))

    assert calibrate_main([str(tmp_path / "a"), "--data", str(scan_data), "--split", "train",
                           "--out", str(tmp_path / "cal")]) == 0
    out = tmp_path / "guided.json"
    assert evaluate_main([str(tmp_path / "cal"), "--data", str(scan_data), "--split", "train", "--limit", "4",
                          "--resolution", "32", "--keep-scan", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    assert res["shapes"] == 4 and all(r["chamfer_x1e3"] is not None for r in res["per_shape"])
    # the picture of what the service sends: scan, truth, the fused output, its depth colours
    from research.figures import TILE, figure
    fused = figure(str(scan_data), [("guided", str(tmp_path / "cal"))], split="train", shapes=2, keep_scan=True)
    alone = figure(str(scan_data), [("guided", str(tmp_path / "cal"))], split="train", shapes=2)
    assert fused.size == alone.size == (4 * TILE, 18 + 2 * TILE)
    column = (2 * TILE, 18, 3 * TILE, 18 + 2 * TILE)         # the output
    assert np.abs(np.asarray(fused.crop(column), float) - np.asarray(alone.crop(column), float)).mean() > 1
    # the keep_scan bias chosen for the run is carried by its bundle
    assert calibrate_main([str(tmp_path / "cal"), "--data", str(scan_data), "--split", "train", "--keep-scan",
                           "--limit", "2", "--resolution", "32"]) == 0
    chosen = json.loads((tmp_path / "cal" / "keep_scan.json").read_text())["empty_bias"]
    meta = export(tmp_path / "cal", tmp_path / "bundle")
    assert meta["format"] == 2 and meta["octree"]["guided"] is True
    assert meta["export"]["self_check"]["max_relative_error"] <= meta["export"]["self_check"]["relative_tolerance"]
    bundle = load_bundle(tmp_path / "bundle")
    assert bundle.octree.guided and bundle.keep_scan_bias == {int(d): b for d, b in chosen.items()}
    # served through onnxruntime (encoder features, key lookup, skip inputs): torch's figures
    for name, extra in (("torch", []), ("served", ["--bundle", str(tmp_path / "bundle")])):
        assert evaluate_main([str(tmp_path / "cal"), "--data", str(scan_data), "--split", "train", "--limit", "4",
                              "--resolution", "32", "--out", str(tmp_path / f"{name}.json"), *extra]) == 0
    a, b = (json.loads((tmp_path / f"{n}.json").read_text())["per_shape"] for n in ("torch", "served"))
    assert [r["chamfer_x1e3"] for r in b] == pytest.approx([r["chamfer_x1e3"] for r in a], rel=0.02)
