"""The dataset build: records, manifest, resume after a kill, and real layouts in the same format."""

import dataclasses
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import trimesh
from PIL import Image

from model.data.__main__ import main
from model.data.dataset import BuildConfig, build_dataset, layout_tasks, load_record, procedural_tasks
from model.octree import LEAF

from .test_layouts import CUBE_OFF_BODY, _write

REPO = Path(__file__).resolve().parents[2]
SMALL = BuildConfig(depth=5, views=2, render_size=32, partial_scans=2, scan_resolution=64)


def test_records_hold_scan_octrees_renders_and_partial_scans(tmp_path):
    tasks = procedural_tasks(1, categories=("chair", "airplane"))
    manifest = build_dataset(tmp_path, tasks, SMALL, workers=1, progress=False)
    assert [r["category"] for r in manifest["records"]] == ["airplane", "chair"]
    assert sum(manifest["splits"].values()) == 2
    assert json.loads((tmp_path / "manifest.json").read_text()) == manifest
    for row in manifest["records"]:
        rec = load_record(tmp_path / row["path"])
        assert str(rec["category"]) == row["category"] and len(rec["points"]) == row["points"] > 1000
        pts = rec["points"]
        assert np.abs(pts).max() <= 0.5 + 1e-3                     # unit bounding box, centred
        ad, full = rec.octree("adaptive"), rec.octree("full")
        assert ad.depth == full.depth == 5 and ad.adaptive and not full.adaptive
        assert sum(ad.nodes_per_depth()) < sum(full.nodes_per_depth()) == row["full_nodes"]
        assert all(lv.neighbors is not None for lv in ad.levels)
        assert any(np.any(lv.label == LEAF) for lv in ad.levels[:-1])
        assert rec["images"].shape == (2, 32, 32, 4) and rec["cameras"].shape == (2, 5)
        assert rec["images"][..., 3].max() == 255 and rec["images"][:, 0, 0, 3].max() == 0
        for i in range(2):
            p, n = rec.partial(i)
            assert 0 < len(p) < len(pts) and p.shape == n.shape
        import hashlib
        assert hashlib.sha256((tmp_path / row["path"]).read_bytes()).hexdigest() == row["sha256"]


def test_build_is_deterministic_and_resume_skips_finished_records(tmp_path):
    tasks = procedural_tasks(1, seed=3, categories=("table", "lamp"))
    build_dataset(tmp_path / "a", tasks, SMALL, progress=False)
    build_dataset(tmp_path / "b", tasks, SMALL, progress=False)
    for t in tasks:
        a, b = load_record(tmp_path / "a" / t.relpath), load_record(tmp_path / "b" / t.relpath)
        for k in ("points", "adaptive_key", "full_plane", "images", "partial_points"):
            assert np.array_equal(a[k], b[k]), k
    assert (tmp_path / "a" / "manifest.json").read_bytes() == (tmp_path / "b" / "manifest.json").read_bytes()
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "b")]) == 0
    before = {t.relpath: os.stat(tmp_path / "a" / t.relpath).st_mtime_ns for t in tasks}
    (tmp_path / "a" / tasks[0].relpath).write_bytes(b"corrupt")     # a damaged record is rebuilt
    build_dataset(tmp_path / "a", tasks, SMALL, progress=False)
    after = {t.relpath: os.stat(tmp_path / "a" / t.relpath).st_mtime_ns for t in tasks}
    assert after[tasks[1].relpath] == before[tasks[1].relpath]
    assert load_record(tmp_path / "a" / tasks[0].relpath)["points"].shape[1] == 3
    # A changed configuration rebuilds everything.
    other = BuildConfig(depth=4, views=1, render_size=16, partial_scans=0, scan_resolution=48)
    m = build_dataset(tmp_path / "a", tasks, other, progress=False)
    assert all(load_record(tmp_path / "a" / r["path"]).octree().depth == 4 for r in m["records"])


def test_a_killed_build_leaves_no_corrupt_record_and_resumes(tmp_path):
    out = tmp_path / "ds"
    cmd = [sys.executable, "-m", "model.data", "build", "--out", str(out), "--per-category", "2",
           "--categories", "chair", "table", "sofa", "--depth", "5", "--views", "2",
           "--render-size", "32", "--partial", "1", "--scan-resolution", "64", "--workers", "1", "--quiet"]
    proc = subprocess.Popen(cmd, cwd=REPO)
    deadline = time.time() + 120
    def finished():             # whole records only: tmp-* files are being written (or renamed away)
        return sorted(p for p in out.glob("records/*/*.npz") if not p.name.startswith("tmp-"))

    while time.time() < deadline and len(finished()) < 2:
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done = finished()
    assert 2 <= len(done) < 6 and not (out / "manifest.json").exists()
    for path in done:                                   # every finished file is a whole record
        assert load_record(path)["points"].ndim == 2
    mtimes = {p: p.stat().st_mtime_ns for p in done}
    assert subprocess.run(cmd, cwd=REPO).returncode == 0
    manifest = json.loads((out / "manifest.json").read_text())
    assert len(manifest["records"]) == 6
    assert all(p.stat().st_mtime_ns == t for p, t in mtimes.items())     # not rebuilt
    assert not list(out.rglob("tmp-*"))


def test_real_layouts_build_records_of_the_same_format(tmp_path):
    mn = tmp_path / "ModelNet40"
    _write(mn / "chair" / "train" / "chair_0001.off", "OFF8 6 0\n" + CUBE_OFF_BODY)
    _write(mn / "table" / "test" / "table_0400.off", "OFF\n8 6 0\n" + CUBE_OFF_BODY)
    r2n2, sn = tmp_path / "ShapeNetRendering", tmp_path / "ShapeNetCore.v2"
    model = "1a2b3c"
    _write(sn / "03001627" / model / "models" / "model_normalized.obj",
           "\n".join(f"v {x} {y} {z}" for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)) + "\n"
           + "f 1 2 4\nf 1 4 3\nf 5 7 8\nf 5 8 6\nf 1 5 6\nf 1 6 2\nf 3 4 8\nf 3 8 7\nf 1 3 7\nf 1 7 5\nf 2 6 8\nf 2 8 4\n")
    rend = r2n2 / "03001627" / model / "rendering"
    rend.mkdir(parents=True)
    for i in range(3):
        Image.fromarray(np.full((137, 137, 4), 40 * i, np.uint8)).save(rend / f"{i:02d}.png")
    (rend / "rendering_metadata.txt").write_text("".join(f"{30 * i} 25 0 0.8 25\n" for i in range(3)))
    (rend / "renderings.txt").write_text("".join(f"{i:02d}.png\n" for i in range(3)))
    folder = tmp_path / "mine"
    _write(folder / "my_bracket.off", "OFF\n8 6 0\n" + CUBE_OFF_BODY)
    keys = None
    for source, root, extra in (("modelnet40", mn, {}), ("r2n2", r2n2, {"shapenet_root": str(sn)}),
                                ("folder", folder, {})):
        tasks = layout_tasks(source, str(root), **extra)
        m = build_dataset(tmp_path / source, tasks, SMALL, progress=False)
        assert len(m["records"]) == len(tasks) > 0
        rec = load_record(tmp_path / source / m["records"][0]["path"])
        keys = set(rec.arrays) if keys is None else keys
        assert set(rec.arrays) == keys                                  # one record format
        assert rec.octree().depth == 5
        if source == "folder":
            assert [(r["category"], r["shape_id"], r["split"]) for r in m["records"]] == [("unknown", "my_bracket", "test")]
            assert rec["images"].shape == (SMALL.views, SMALL.render_size, SMALL.render_size, 4)
            assert len(rec["partial_offsets"]) == SMALL.partial_scans + 1
        if source == "r2n2":
            assert rec["images"].shape == (3, 137, 137, 4)
            assert np.allclose(rec["cameras"][:, 0], [0, 30, 60])
    with pytest.raises(ValueError, match="no mesh"):
        layout_tasks("r2n2", str(r2n2))


def test_cli_reports_bad_arguments_in_one_line(tmp_path):
    for args, msg in ((["--per-category", "1", "--depth", "1"], "--depth"),
                      (["--depth", "5"], "--per-category"),
                      (["--per-category", "1", "--categories", "spaceship"], "unknown categories"),
                      (["--source", "modelnet40", "--per-category", "1"], "--root"),
                      (["--source", "modelnet40", "--root", str(tmp_path / "none")], "is not a directory"),
                      (["--source", "folder", "--root", str(tmp_path)], "holds no mesh files")):
        proc = subprocess.run([sys.executable, "-m", "model.data", "build", "--out", str(tmp_path / "o"), *args],
                              cwd=REPO, capture_output=True, text=True, timeout=60)
        assert proc.returncode == 2, proc.stderr
        assert len(proc.stderr.strip().splitlines()) == 1 and msg in proc.stderr


def test_a_second_generator_build_names_it_and_a_first_keeps_its_old_manifest(tmp_path):
    tasks = procedural_tasks(1, seed=3, categories=("chair",))
    first = build_dataset(tmp_path / "v1", tasks, SMALL, progress=False)
    assert "generator" not in first["config"] and BuildConfig(**first["config"]) == SMALL
    settings = {k: v for k, v in dataclasses.asdict(SMALL).items() if k not in ("generator", "up")}
    assert first["config_fingerprint"] == hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]
    wider = dataclasses.replace(SMALL, generator=2)
    second = build_dataset(tmp_path / "v2", tasks, wider, progress=False)
    assert second["config"]["generator"] == 2 and BuildConfig(**second["config"]) == wider
    assert second["config_fingerprint"] != first["config_fingerprint"]
    a, b = (load_record(tmp_path / v / tasks[0].relpath)["points"] for v in ("v1", "v2"))
    assert a.shape != b.shape or not np.allclose(a, b)
    build_dataset(tmp_path / "v1", tasks, wider, progress=False)    # a changed generator rebuilds
    c = load_record(tmp_path / "v1" / tasks[0].relpath)["points"]
    assert np.array_equal(b, c)
    proc = subprocess.run([sys.executable, "-m", "model.data", "build", "--out", str(tmp_path / "o"), "--source",
                           "modelnet40", "--root", str(tmp_path), "--generator", "2"],
                          cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "--generator applies to --source procedural only" in proc.stderr


def test_real_meshes_turned_y_up_name_it_and_the_default_keeps_old_fingerprints(tmp_path):
    folder = tmp_path / "mine"
    folder.mkdir()
    trimesh.creation.box(extents=(0.5, 0.5, 2.0)).export(folder / "post.stl")     # a z-up post
    tasks = layout_tasks("folder", str(folder))
    as_read = build_dataset(tmp_path / "y", tasks, SMALL, progress=False)
    assert "up" not in as_read["config"] and as_read["config_fingerprint"] == SMALL.fingerprint()
    settings = {k: v for k, v in dataclasses.asdict(SMALL).items() if k not in ("generator", "up")}
    assert SMALL.fingerprint() == hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]
    turned = build_dataset(tmp_path / "z", tasks, dataclasses.replace(SMALL, up="z"), progress=False)
    assert turned["config"]["up"] == "z" and turned["config_fingerprint"] != SMALL.fingerprint()
    spans = {k: np.ptp(load_record(tmp_path / k / tasks[0].relpath)["points"], axis=0) for k in ("y", "z")}
    assert spans["y"].argmax() == 2 and spans["z"].argmax() == 1          # the post stands along y once turned
    assert np.allclose(np.sort(spans["y"]), np.sort(spans["z"]), atol=0.02)
    proc = subprocess.run([sys.executable, "-m", "model.data", "build", "--out", str(tmp_path / "o"),
                           "--per-category", "1", "--up", "z"], cwd=REPO, capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2 and "--up applies to real meshes only" in proc.stderr


def test_two_shards_and_a_merge_equal_a_single_build_byte_for_byte(tmp_path):
    from model.data.dataset import Shard, merge_shards

    tasks = procedural_tasks(4, categories=("chair", "car", "lamp"))
    single = build_dataset(tmp_path / "single", tasks, SMALL, progress=False)
    parts = [build_dataset(tmp_path / f"part{k}", tasks, SMALL, progress=False, shard=Shard(k, 2)) for k in (0, 1)]
    assert all(p["records"] for p in parts)                             # both shards got work
    assert sum(len(p["records"]) for p in parts) == len(single["records"]) == 12
    assert not (tmp_path / "part0" / "manifest.json").exists()          # a shard writes its own manifest
    merged = merge_shards(tmp_path / "merged", [tmp_path / "part0", tmp_path / "part1"])
    assert merged == single
    assert (tmp_path / "merged" / "manifest.json").read_bytes() == (tmp_path / "single" / "manifest.json").read_bytes()
    for r in single["records"]:
        assert (tmp_path / "merged" / r["path"]).read_bytes() == (tmp_path / "single" / r["path"]).read_bytes()
    # shards in one shared folder merge in place too, through the CLI
    for k in (0, 1):
        build_dataset(tmp_path / "shared", tasks, SMALL, progress=False, shard=Shard(k, 2))
    assert main(["merge", "--out", str(tmp_path / "shared"), str(tmp_path / "shared")]) == 0
    assert (tmp_path / "shared" / "manifest.json").read_bytes() == (tmp_path / "single" / "manifest.json").read_bytes()


def test_merge_refuses_missing_duplicate_foreign_or_damaged_shards(tmp_path, capsys):
    from model.data.dataset import Shard, merge_shards

    tasks = procedural_tasks(3, categories=("chair", "car"))
    for k in range(3):
        build_dataset(tmp_path / f"p{k}", tasks, SMALL, progress=False, shard=Shard(k, 3))
    with pytest.raises(ValueError, match=r"shards \[2\] of 3 are missing"):
        merge_shards(tmp_path / "m", [tmp_path / "p0", tmp_path / "p1"])
    with pytest.raises(ValueError, match="also in"):
        merge_shards(tmp_path / "m", [tmp_path / "p0", tmp_path / "p0", tmp_path / "p1", tmp_path / "p2"])
    other = BuildConfig(depth=4, views=1, render_size=16, partial_scans=0, scan_resolution=48)
    build_dataset(tmp_path / "q", tasks, other, progress=False, shard=Shard(2, 3))
    with pytest.raises(ValueError, match="another config"):
        merge_shards(tmp_path / "m", [tmp_path / "p0", tmp_path / "p1", tmp_path / "q"])
    rec = next(f for k in range(3) for f in (tmp_path / f"p{k}").rglob("*.npz"))
    rec.write_bytes(rec.read_bytes()[:-10] + b"0123456789")
    with pytest.raises(ValueError, match="sha256 differs"):
        merge_shards(tmp_path / "m", [tmp_path / "p0", tmp_path / "p1", tmp_path / "p2"])
    assert main(["merge", "--out", str(tmp_path / "m"), str(tmp_path / "empty")]) == 2
    assert "no shard manifests" in capsys.readouterr().err
    for bad in ("3/3", "-1/2", "a/b", "1"):
        assert main(["build", "--out", str(tmp_path / "x"), "--per-category", "1", f"--shard={bad}"]) == 2
        assert "--shard must be K/N" in capsys.readouterr().err


def test_compare_tells_rounding_from_structure(tmp_path, capsys):
    from model.data.compare import compare_datasets
    from model.data.dataset import write_npz_atomic

    tasks = procedural_tasks(1, seed=4, categories=("chair", "car"))
    build_dataset(tmp_path / "a", tasks, SMALL, progress=False)
    shutil.copytree(tmp_path / "a", tmp_path / "b")
    manifest = json.loads((tmp_path / "b" / "manifest.json").read_text())
    row = manifest["records"][0]
    arrays = load_record(tmp_path / "b" / row["path"]).arrays
    arrays["full_plane"] = arrays["full_plane"] + np.float32(1e-6)          # rounding-sized
    row["sha256"] = write_npz_atomic(tmp_path / "b" / row["path"], arrays)
    (tmp_path / "b" / "manifest.json").write_text(json.dumps(manifest))
    c = compare_datasets(tmp_path / "a", tmp_path / "b")
    assert (c.compared, c.same_bytes, c.same_structure) == (2, 1, True)
    assert set(c.arrays) == {"full_plane"} and 5e-7 < c.arrays["full_plane"].max_abs < 2e-6
    arrays["adaptive_label"] = arrays["adaptive_label"][::-1].copy()          # another tree
    row["sha256"] = write_npz_atomic(tmp_path / "b" / row["path"], arrays)
    (tmp_path / "b" / "manifest.json").write_text(json.dumps(manifest))
    assert main(["compare", str(tmp_path / "a"), str(tmp_path / "b")]) == 1
    assert "adaptive_label: differs in 1 records, 1 in shape or integer values" in capsys.readouterr().out


def test_building_only_some_splits_makes_the_same_records_as_a_whole_build(tmp_path):
    whole, some = tmp_path / "whole", tmp_path / "some"
    args = ["build", "--per-category", "12", "--categories", "chair", "--depth", "4", "--views", "1",
            "--render-size", "16", "--partial", "0", "--workers", "1", "--quiet"]
    assert main([*args, "--out", str(whole)]) == 0
    assert main([*args, "--out", str(some), "--splits", "val", "test"]) == 0
    rows = json.loads((whole / "manifest.json").read_text())["records"]
    kept = json.loads((some / "manifest.json").read_text())["records"]
    assert kept == [r for r in rows if r["split"] in ("val", "test")]
    assert 0 < len(kept) < len(rows)
    assert all((some / r["path"]).read_bytes() == (whole / r["path"]).read_bytes() for r in kept)
    # the other split built later into the same folder: the manifest lists both, as a whole build's
    assert main([*args, "--out", str(some), "--splits", "train"]) == 0
    assert json.loads((some / "manifest.json").read_text())["records"] == rows
    assert main([*args, "--out", str(some), "--splits", "test"]) == 0      # nothing to build: the same
    assert json.loads((some / "manifest.json").read_text())["records"] == rows
