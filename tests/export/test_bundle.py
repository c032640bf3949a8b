"""Bundle verification refuses what is incomplete, tampered, too new or inconsistent; the serving
side (bundle, runtime, decode loop, preprocessing) runs with torch absent; threads follow cgroups."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

from export.__main__ import main as export_main
from export.bundle import MANIFEST, BundleError, load_bundle
from export.runtime import Runtime, available_cpus

from ..torchless import run_without_torch


@pytest.fixture
def bundle_copy(exported, tmp_path):
    _, _, folder = exported("aocnn")
    dst = tmp_path / "bundle"
    shutil.copytree(folder, dst)
    return dst


def _edit_manifest(folder: Path, edit) -> None:
    meta = json.loads((folder / MANIFEST).read_text())
    edit(meta)
    (folder / MANIFEST).write_text(json.dumps(meta))


def test_a_bundle_with_one_flipped_byte_is_refused_naming_the_file(bundle_copy):
    target = bundle_copy / "decoder_predict_4.onnx"
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0x01
    target.write_bytes(bytes(data))
    with pytest.raises(BundleError, match=r"decoder_predict_4\.onnx: sha256 .* does not match"):
        load_bundle(bundle_copy)


@pytest.mark.parametrize("case, edit, message", [
    ("newer format", lambda m: m.update(format=3), r"format 3 is newer than this software reads \(2\)"),
    ("guided without skip outputs", lambda m: m["octree"].update(guided=True),
     r"guided bundle's octree_encoder must output skip_2\.\.skip_5"),
    ("guided not a boolean", lambda m: m["octree"].update(guided="yes"), r"guided must be true or false"),
    ("graph left out", lambda m: m["graphs"].pop("decoder_expand_3"), r"needs the graphs decoder_expand_3"),
    ("unknown task", lambda m: m.update(task="segmentation"), r"unknown task 'segmentation'"),
    ("path outside", lambda m: m["graphs"]["decoder_start"].update(file="../x.onnx"), r"plain \.onnx file name"),
    ("no octree", lambda m: m.pop("octree"), r"missing 'octree'"),
    ("bad depths", lambda m: m["octree"].update(adaptive_depth=9), r"adaptive_depth <= depth"),
    ("keep_scan bias too deep", lambda m: m["output"].update(keep_scan={"empty_bias": {"9": 1.0}}),
     r"output\.keep_scan\.empty_bias must map depths"),
    ("keep_scan bias not a number", lambda m: m["output"].update(keep_scan={"empty_bias": {"5": "high"}}),
     r"output\.keep_scan\.empty_bias must map depths"),
    ("keep_scan not a mapping", lambda m: m["output"].update(keep_scan=[1]), r"output\.keep_scan\.empty_bias"),
])
def test_an_inconsistent_manifest_is_refused_saying_what_is_wrong(bundle_copy, case, edit, message):
    _edit_manifest(bundle_copy, edit)
    with pytest.raises(BundleError, match=message):
        load_bundle(bundle_copy)


def test_a_guided_bundle_whose_decoder_does_not_read_the_skips_is_refused(exported, tmp_path):
    shutil.copytree(exported("completion-guided")[2], tmp_path / "guided")
    assert load_bundle(tmp_path / "guided").octree.guided
    _edit_manifest(tmp_path / "guided", lambda m: m["graphs"]["decoder_predict_4"]["inputs"].pop("skip_index"))
    with pytest.raises(BundleError, match="decoder_predict_4 must read skip and skip_index"):
        load_bundle(tmp_path / "guided")


def test_missing_files_and_non_bundles_are_refused(bundle_copy, tmp_path):
    (bundle_copy / "decoder_start.onnx").unlink()
    with pytest.raises(BundleError, match=r"decoder_start\.onnx: missing"):
        load_bundle(bundle_copy)
    with pytest.raises(BundleError, match="no such directory"):
        load_bundle(tmp_path / "nowhere")
    (tmp_path / "empty").mkdir()
    with pytest.raises(BundleError, match="model.json: missing"):
        load_bundle(tmp_path / "empty")
    (tmp_path / "empty" / MANIFEST).write_text("{not json")
    with pytest.raises(BundleError, match="not valid JSON"):
        load_bundle(tmp_path / "empty")


def test_graph_inputs_that_do_not_match_the_spec_are_refused(bundle_copy):
    _edit_manifest(bundle_copy, lambda m: m["graphs"]["decoder_predict_3"]["inputs"]["neighbors"].update(dtype="float32"))
    with pytest.raises(BundleError, match=r"decoder_predict_3\.onnx: input 'neighbors' is tensor\(int64\)"):
        Runtime(load_bundle(bundle_copy), threads=1)
    # a graph swapped for another one with a valid checksum: names do not match
    _edit_manifest(bundle_copy, lambda m: m["graphs"]["decoder_predict_3"]["inputs"]["neighbors"].update(dtype="int64"))
    spec = json.loads((bundle_copy / MANIFEST).read_text())["graphs"]
    shutil.copy(bundle_copy / "decoder_expand_3.onnx", bundle_copy / "decoder_predict_3.onnx")
    _edit_manifest(bundle_copy, lambda m: m["graphs"]["decoder_predict_3"].update(sha256=spec["decoder_expand_3"]["sha256"]))
    with pytest.raises(BundleError, match=r"decoder_predict_3\.onnx: graph inputs \['features', 'split'\]"):
        Runtime(load_bundle(bundle_copy), threads=1)


def test_the_cli_verifies_a_bundle_and_exits_2_with_one_line_on_a_bad_one(bundle_copy, capsys):
    assert export_main(["--verify", str(bundle_copy)]) == 0
    out = capsys.readouterr().out
    assert ": OK  autoencoder" in out and "graphs" in out
    _edit_manifest(bundle_copy, lambda m: m.update(format=7))
    assert export_main(["--verify", str(bundle_copy)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("error: ") and "format 7" in err


def test_export_refuses_to_overwrite_and_non_checkpoints_with_exit_2(exported, tmp_path, capsys):
    _, _, folder = exported("aocnn")
    assert export_main([str(tmp_path), "--out", str(tmp_path / "b")]) == 2
    assert "neither a run folder" in capsys.readouterr().err
    assert export_main([str(folder.parent / "checkpoint"), "--out", str(folder)]) == 2
    assert "already exists; pass --force" in capsys.readouterr().err
    assert not (tmp_path / "b").exists() and not list(tmp_path.glob("tmp-*"))


def test_the_serving_side_runs_with_torch_absent(exported):
    """The bundle loader, runtime, decode loop, octree core and preprocessing import no torch."""
    _, _, folder = exported("aocnn")
    done = run_without_torch(f"""
        import numpy as np
        from export.bundle import load_bundle
        from export.runtime import Runtime
        import export.__main__, model.decode, model.image.frame, model.octree, model.octree.patches
        runtime = Runtime(load_bundle({str(folder)!r}), threads=1)
        from model.octree import build_octree
        rng = np.random.default_rng(0)
        pts = rng.normal(size=(5000, 3)); pts /= np.linalg.norm(pts, axis=1, keepdims=True)
        octree = runtime.decode(runtime.encode_octree(build_octree((pts, pts), 5)))
        print("leaves", sum(octree.leaves_per_depth()))
    """)
    assert done.returncode == 0, done.stderr
    assert int(done.stdout.split()[-1]) > 0


def test_threads_follow_the_cgroup_quota_and_affinity(tmp_path, exported, monkeypatch):
    import os
    affinity = len(os.sched_getaffinity(0))
    (tmp_path / "cpu.max").write_text("150000 100000\n")
    assert available_cpus(tmp_path) == min(affinity, 2)
    (tmp_path / "cpu.max").write_text("50000 100000\n")
    assert available_cpus(tmp_path) == 1
    (tmp_path / "cpu.max").write_text("max 100000\n")
    assert available_cpus(tmp_path) == affinity
    (tmp_path / "cpu.max").unlink()
    (tmp_path / "cpu").mkdir()
    (tmp_path / "cpu" / "cpu.cfs_quota_us").write_text("-1\n")
    (tmp_path / "cpu" / "cpu.cfs_period_us").write_text("100000\n")
    assert available_cpus(tmp_path) == affinity
    assert available_cpus(tmp_path / "absent") == affinity
    import export.runtime as rt
    monkeypatch.setattr(rt, "available_cpus", lambda: 3)     # sessions get what the process may use
    runtime = Runtime(load_bundle(exported("aocnn")[2]))
    assert runtime.threads == 3


def test_exporting_the_same_checkpoint_again_gives_the_same_bytes_and_no_machine_paths(exported, tmp_path):
    """The exporter's debug records (source stack traces with this machine's paths, FX names) are
    stripped, so a bundle is a function of the checkpoint and the package versions only."""
    from export.exporter import export

    _, _, folder = exported("classify-aocnn")
    again = tmp_path / "again"
    export(folder.parent / "checkpoint", again)
    files = sorted(p.name for p in folder.iterdir())
    assert files == sorted(p.name for p in again.iterdir()) and any(f.endswith(".onnx") for f in files)
    for name in files:
        assert (folder / name).read_bytes() == (again / name).read_bytes(), name
        if name.endswith(".onnx"):
            data = (folder / name).read_bytes()
            assert b"site-packages" not in data and b".py\"" not in data and b"stack_trace" not in data, name
