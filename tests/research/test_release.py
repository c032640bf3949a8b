"""research.release: a run packaged as a shipped checkpoint (half precision, provenance, the
evaluation recorded), from its recipe or trained by hand."""

import json

import torch

from model.train.loop import Trainer

from ..conftest import TINY
from ..model.test_train import config


def test_a_released_checkpoint_is_stored_in_half_precision_and_evaluated_as_stored(tiny_data, tmp_path):
    """research.release packages the run's weights as float16; the checkpoint folder loads as float32
    weights equal to the rounded ones, and its evaluation is recorded in model.json."""
    from model.checkpoint import load_model
    from research.evaluate import main as evaluate_main
    from research.recipe import load_recipe
    from research.release import package, record_evaluation

    Trainer(config(tiny_data, tmp_path / "run", iters=2)).run()
    out = tmp_path / "shipped"
    meta = package(tmp_path / "run", tiny_data, out, load_recipe("completion"), ["completion", "--workdir", "w"])
    stored = torch.load(out / "model.pt", weights_only=True)
    assert meta["weights_dtype"] == "float16" and meta["evaluation"] is None
    assert {v.dtype for v in stored.values() if v.is_floating_point()} == {torch.float16}
    trained = torch.load(tmp_path / "run" / "checkpoint.pt", weights_only=False)["model"]
    loaded = load_model(out).model.state_dict()
    for k, v in trained.items():
        assert loaded[k].dtype == v.dtype and torch.equal(loaded[k], v.half().to(v.dtype)), k
    assert "keep_scan" not in meta and "mask_guide" not in meta
    # a decode setting chosen for the run's weights (research.calibrate --keep-scan) goes with them
    chosen = {"empty_bias": {"5": 1.0}, "split": "val"}
    (tmp_path / "run" / "keep_scan.json").write_text(json.dumps(chosen))
    again = package(tmp_path / "run", tiny_data, tmp_path / "again", load_recipe("completion"), ["completion"])
    assert again["keep_scan"] == chosen and load_model(tmp_path / "again").meta["keep_scan"] == chosen
    assert evaluate_main([str(out), "--data", str(tiny_data), "--split", "val", "--out", str(tmp_path / "e.json")]) == 0
    meta = record_evaluation(out, json.loads((tmp_path / "e.json").read_text()))
    assert meta["evaluation"]["shapes"] > 0 and "per_shape" not in meta["evaluation"]
    assert load_model(out).meta["evaluation"] == meta["evaluation"]


def test_release_packages_a_run_trained_by_hand_without_claiming_the_recipe(tiny_data, tmp_path, capsys):
    """research.release --run: the run's own configuration and steps go into model.json, no recipe
    training command; a missing or damaged run or a run of another task is refused (exit 2, one line) before
    anything is built."""
    from research.recipe import load_recipe
    from research.release import main as release_main
    from research.release import package

    Trainer(config(tiny_data, tmp_path / "run", iters=2)).run()
    meta = package(tmp_path / "run", tiny_data, tmp_path / "shipped", load_recipe("completion"),
                   ["completion", "--workdir", "w", "--run", "run"], by_recipe=False)
    assert meta["train_command"] is None and meta["recipe"] is None
    assert meta["steps"] == 2 and meta["config"]["iters"] == 2 and meta["command"].endswith("--run run")
    work = tmp_path / "work"
    assert release_main(["foreground", "--workdir", str(work), "--run", str(tmp_path / "nothing")]) == 2
    assert "neither a run folder (checkpoint.pt) nor a checkpoint folder" in capsys.readouterr().err
    (tmp_path / "damaged").mkdir()
    (tmp_path / "damaged" / "checkpoint.pt").write_bytes(b"not a checkpoint")
    assert release_main(["foreground", "--workdir", str(work), "--run", str(tmp_path / "damaged")]) == 2
    assert "not a readable checkpoint" in capsys.readouterr().err
    assert release_main(["foreground", "--workdir", str(work), "--run", str(tmp_path / "run")]) == 2
    assert "not a foreground run" in capsys.readouterr().err
    assert release_main(["foreground", "--workdir", str(work), "--data", str(tiny_data)]) == 2
    assert "--data goes with --run" in capsys.readouterr().err
    assert not work.exists()


def test_release_packages_a_run_with_the_dataset_it_was_trained_on(tiny_data, tmp_path, capsys):
    """research.release --run RUN --data DIR: nothing is built; DIR's manifest is the provenance and its
    test split the evaluation recorded in model.json.  A folder without a manifest or of another depth
    is refused (exit 2, one line) before anything is written."""
    from model.data.dataset import build_dataset, procedural_tasks
    from research.release import main as release_main

    data = tmp_path / "data"            # chairs: 4 shapes to train on, 2 of the test split
    tasks = procedural_tasks(30, categories=("chair",))
    build_dataset(data, tasks[:4] + [t for t in tasks if t.split == "test"][:2], TINY, workers=1, progress=False)
    Trainer(config(data, tmp_path / "run", task="image", encoder="lenet", encoder_width=4, image_size=32,
                   iters=2)).run()
    work, out = tmp_path / "work", tmp_path / "shipped"
    (tmp_path / "deeper").mkdir()
    (tmp_path / "deeper" / "manifest.json").write_text(json.dumps({"config": {"depth": 6}}))
    for folder, needle in ((tmp_path / "deeper", "built at depth 6, but"), (tmp_path, "no manifest.json"),
                           (tiny_data, "is not the dataset")):
        assert release_main(["image-to-shape", "--workdir", str(work), "--run", str(tmp_path / "run"), "--data", str(folder),
                             "--out", str(out)]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1
        assert not work.exists() and not out.exists()
    assert release_main(["image-to-shape", "--workdir", str(work), "--run", str(tmp_path / "run"), "--data", str(data),
                         "--out", str(out)]) == 0
    meta = json.loads((out / "model.json").read_text())
    manifest = json.loads((data / "manifest.json").read_text())
    assert meta["data"]["build"] == manifest["config"] and meta["data"]["build_command"] is None
    assert meta["train_command"] is None and meta["steps"] == 2
    assert meta["evaluation"]["split"] == "test" and meta["evaluation"]["shapes"] == 2
    assert not (work / "data").exists() and "test Chamfer" in capsys.readouterr().out


def test_provenance_names_a_run_as_the_repository_does(tmp_path, monkeypatch):
    """A teacher trained elsewhere on the disk (/disk/runs/ae7) is recorded as the repository's link
    names it (runs/ae7 for runs -> /disk/runs), a folder inside the repository relative to it; other
    absolute paths, relative paths and None are kept."""
    from research.release import _named_here

    disk, repo = tmp_path / "disk", tmp_path / "repo"
    (disk / "runs" / "ae7").mkdir(parents=True)
    (repo / "work" / "teacher").mkdir(parents=True)
    (repo / "runs").symlink_to(disk / "runs")
    monkeypatch.chdir(repo)
    assert _named_here(str(disk / "runs" / "ae7")) == "runs/ae7"
    assert _named_here(str(repo / "work" / "teacher")) == "work/teacher"
    assert _named_here(str(tmp_path / "elsewhere")) == str(tmp_path / "elsewhere")
    assert _named_here("runs/ae7") == "runs/ae7" and _named_here(None) is None
