"""The training command: resume to identical weights, DDP gradients, metrics and evaluation."""

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from model.train.loop import TrainConfig, Trainer

REPO = Path(__file__).resolve().parents[2]


def config(data, out, **kw):
    base = dict(data=str(data), depth=5, arch="aocnn", out=str(out), iters=12, batch_size=4,
                val_every=6, ckpt_every=4, latent=32, channels=4, progress=False)
    base.update(kw)
    return TrainConfig(**base)


def trains_and_resumes_identically(data, tmp_path, **kw) -> tuple[Trainer, dict]:
    """Train 6 steps straight (run ``a``) and 3 + 3 with a restart (run ``b``); assert equal
    weights; returns the straight trainer and its summary."""
    kw = dict(iters=6, ckpt_every=3, val_every=3, **kw)
    straight = Trainer(config(data, tmp_path / "a", **kw))
    summary = straight.run()
    half = Trainer(config(data, tmp_path / "b", **kw))
    for _ in range(3):
        half.train_step()
    half.save()
    resumed = Trainer(config(data, tmp_path / "b", **kw))
    assert resumed.step == 3
    resumed.run()
    a, b = straight.model.state_dict(), resumed.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    return straight, summary


def test_checkpoint_resumes_to_identical_weights(tiny_data, tmp_path):
    straight = Trainer(config(tiny_data, tmp_path / "a"))
    straight.run()
    half = Trainer(config(tiny_data, tmp_path / "b"))
    for _ in range(8):                                        # a run killed after its step-8 checkpoint
        half.train_step()
    half.save()
    resumed = Trainer(config(tiny_data, tmp_path / "b"))     # picks up step 8 from the checkpoint
    assert resumed.step == 8
    resumed.run()
    a, b = straight.model.state_dict(), resumed.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    rows = [json.loads(l) for l in (tmp_path / "a" / "metrics.jsonl").read_text().splitlines()]
    assert {r["split"] for r in rows} == {"train", "val"} and rows[-1]["step"] == 12
    with pytest.raises(ValueError, match="channels"):
        Trainer(config(tiny_data, tmp_path / "a", channels=8))


def test_until_ends_a_run_early_on_its_full_schedule_and_a_rerun_goes_on(tiny_data, tmp_path):
    """--until: the run's first steps of the full schedule (the rate as the full run's), validated
    and kept at the step it ends at; rerun without it, it goes on to the weights of the straight run;
    a run already past --until trains no step."""
    straight = Trainer(config(tiny_data, tmp_path / "a", iters=7))
    straight.run()
    early = Trainer(config(tiny_data, tmp_path / "b", iters=7, until=3))
    summary = early.run()
    assert early.step == 3 and summary["steps"] == 3 and (tmp_path / "b" / "steps" / "000003").is_dir()
    rows = [json.loads(l) for l in (tmp_path / "b" / "metrics.jsonl").read_text().splitlines()]
    # the rate drops 10x at int(7 * 2/7) = 2 (then 4, 5): once by step 3; on a 3-step schedule thrice
    assert [r["lr"] for r in rows if r["split"] == "train"] == [pytest.approx(1e-4)]
    assert torch.load(tmp_path / "b" / "checkpoint.pt", weights_only=False)["step"] == 3
    past = Trainer(config(tiny_data, tmp_path / "b", iters=7, until=2))
    assert past.run()["steps"] == 3 and past.step == 3
    resumed = Trainer(config(tiny_data, tmp_path / "b", iters=7))
    resumed.run()
    a, b = straight.model.state_dict(), resumed.model.state_dict()
    assert all(torch.equal(a[k], b[k]) for k in a)
    with pytest.raises(ValueError, match="--until 9 is past the run's last step"):
        Trainer(config(tiny_data, tmp_path / "c", iters=7, until=9))


def _free_port():
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def test_ddp_with_two_processes_gives_the_gradients_of_one_process(tiny_data, tmp_path):
    """Two gloo processes, each on half of a batch, against one process averaging the halves."""
    script = tmp_path / "grads.py"
    script.write_text(f"""
import os, sys, torch
sys.path.insert(0, {str(REPO)!r})
from model.train.loop import TrainConfig, Trainer
cfg = TrainConfig(data={str(tiny_data)!r}, depth=5, arch="aocnn", out={str(tmp_path / 'ddp')!r},
                  iters=1, batch_size=4, latent=32, channels=4, progress=False)
t = Trainer(cfg)
t.model.train()
loss = t.losses(t.train_set, t.batch_indices(0))["total"]
loss.backward()
if t.rank == 0:
    torch.save({{n: p.grad for n, p in t.model.named_parameters()}}, {str(tmp_path / 'ddp.pt')!r})
t.close()
assert not torch.distributed.is_initialized()
""")
    env = dict(os.environ, MASTER_ADDR="127.0.0.1", MASTER_PORT=str(_free_port()), WORLD_SIZE="2")
    procs = [subprocess.Popen([sys.executable, str(script)], env=dict(env, RANK=str(r), LOCAL_RANK=str(r)))
             for r in range(2)]
    assert all(p.wait(timeout=300) == 0 for p in procs)
    ddp = torch.load(tmp_path / "ddp.pt")
    # One process: the same model, the two halves' losses averaged, as DDP averages gradients.
    single = Trainer(TrainConfig(data=str(tiny_data), depth=5, arch="aocnn", out=str(tmp_path / "one"),
                                 iters=1, batch_size=4, latent=32, channels=4, progress=False))
    single.model.train()
    idx = single.batch_indices(0)
    loss = 0.5 * (single.losses(single.train_set, idx[0::2])["total"]
                  + single.losses(single.train_set, idx[1::2])["total"])
    loss.backward()
    for n, p in single.model.named_parameters():
        assert torch.allclose(p.grad, ddp[n], atol=1e-6, rtol=1e-5), n


def test_train_and_evaluate_commands_end_to_end(tiny_data, tmp_path):
    run = tmp_path / "run"
    cmd = [sys.executable, "-m", "model.train", "autoencoder", "--data", str(tiny_data), "--depth", "5",
           "--arch", "aocnn", "--out", str(run), "--iters", "6", "--batch-size", "4", "--channels", "4",
           "--latent", "32", "--structure-loss", "ce", "--pred-hidden", "8", "--quiet"]
    assert subprocess.run(cmd, cwd=REPO, timeout=300).returncode == 0
    out = tmp_path / "results.json"
    proc = subprocess.run([sys.executable, "-m", "research.evaluate", str(run), "--data", str(tiny_data),
                           "--split", "train", "--limit", "3", "--out", str(out), "--resolution", "32",
                           "--mesh-dir", str(tmp_path / "meshes")], cwd=REPO, timeout=300)
    assert proc.returncode == 0
    res = json.loads(out.read_text())
    assert res["shapes"] == 3 and np.isfinite(res["chamfer_x1e3_category_mean"])
    assert len(list((tmp_path / "meshes").glob("*.ply"))) == 3
    rows = res["per_shape"]
    by_cat = {}
    for r in rows:
        by_cat.setdefault(r["category"], []).append(r["chamfer_x1e3"])
    assert {c: np.mean(v) for c, v in by_cat.items()} == pytest.approx(res["chamfer_x1e3"])
    # teacher-forced statuses: every octant of every depth is counted once
    assert sorted(res["status"]) == ["2", "3", "4", "5"]
    assert np.sum(res["status"]["2"]["confusion"]) == 3 * 64
    for d, st in res["status"].items():
        assert np.sum(st["confusion"]) == sum(st["truth_count"].values()) == sum(st["predicted_count"].values())
        assert 0 <= st["accuracy"] <= 1
    # the oracle decodes the true structure: node counts equal the truth's, shape by shape
    oracle = tmp_path / "oracle.json"
    proc = subprocess.run([sys.executable, "-m", "research.evaluate", str(run), "--data", str(tiny_data),
                           "--split", "train", "--limit", "3", "--out", str(oracle), "--resolution", "32",
                           "--oracle", "structure"], cwd=REPO, timeout=300)
    assert proc.returncode == 0
    for r in json.loads(oracle.read_text())["per_shape"]:
        assert r["decoded_nodes"] == r["truth_nodes"]
    # with the true planes too, the decoded patches are the truth's own: the representation floor
    from research.evaluate import main as evaluate_main
    assert evaluate_main([str(run), "--data", str(tiny_data), "--split", "train", "--limit", "3",
                          "--out", str(oracle), "--resolution", "32", "--oracle", "all"]) == 0
    floor = json.loads(oracle.read_text())
    assert floor["chamfer_x1e3_category_mean"] < min(res["chamfer_x1e3_category_mean"], 0.5)
    bad = subprocess.run(cmd[:-1] + ["--depth", "6"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert bad.returncode == 2 and "depth" in bad.stderr and len(bad.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("extra, needle", [
    (["--iters", "0"], "--iters must be at least 1"),
    (["--batch-size", "-1"], "--batch-size must be at least 1"),
    (["--lr", "0"], "--lr must be positive"),
    (["--epochs", "-2"], "--epochs must be positive"),
    (["--until", "0"], "--until must be at least 1"),
    (["--iters", "4", "--until", "5"], "--until 5 is past the run's last step (4)"),
])
def test_train_rejects_bad_settings_in_one_line(tiny_data, tmp_path, capsys, extra, needle):
    from model.train.__main__ import main

    code = main(["autoencoder", "--data", str(tiny_data), "--depth", "5", "--out", str(tmp_path / "r"),
                 "--quiet", *extra])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and needle in err[0]
    assert not (tmp_path / "r").exists()


def test_damaged_checkpoint_run_folder_and_record_give_one_line_errors(tiny_data, tmp_path, capsys):
    import shutil

    from model.train.__main__ import main as train_main
    from research.evaluate import main as evaluate_main

    base = ["autoencoder", "--data", str(tiny_data), "--depth", "5", "--iters", "1", "--quiet"]
    (tmp_path / "afile").write_text("x")
    assert train_main(base + ["--out", str(tmp_path / "afile")]) == 2
    assert "is a file" in capsys.readouterr().err

    run = tmp_path / "run"
    run.mkdir()
    (run / "checkpoint.pt").write_bytes(b"not a checkpoint")
    assert train_main(base + ["--out", str(run)]) == 2
    assert "not a readable checkpoint" in capsys.readouterr().err
    assert evaluate_main([str(run), "--data", str(tiny_data), "--out", str(tmp_path / "e.json")]) == 2
    assert "not a readable checkpoint" in capsys.readouterr().err
    assert evaluate_main([str(run), "--data", str(tiny_data), "--out", str(tmp_path / "no" / "e.json")]) == 2
    assert "does not exist" in capsys.readouterr().err

    data = tmp_path / "data"
    shutil.copytree(tiny_data, data)
    manifest = json.loads((data / "manifest.json").read_text())
    victim = data / manifest["records"][0]["path"]
    victim.write_bytes(victim.read_bytes()[: victim.stat().st_size // 2])
    good = tmp_path / "good"
    assert train_main(["autoencoder", "--data", str(data), "--depth", "5", "--iters", "1", "--quiet",
                       "--out", str(good)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "damaged" in err[0] and victim.name in err[0]
    assert not (tmp_path / "e.json").exists()


@pytest.mark.parametrize("decoder", ["aocnn", "psg", "atlasnet"])
def test_image_training_resumes_and_evaluates_to_a_well_formed_table(tiny_data, tmp_path, decoder):
    """A few steps of shape-from-an-image, killed and resumed to the same weights, then evaluated
    with and without ICP; the results table reads the output."""
    from research.evaluate import main as evaluate_main
    from research.results_table import main as table_main

    kw = dict(task="image", arch=decoder, encoder="lenet", encoder_width=4, image_size=32)
    _, summary = trains_and_resumes_identically(tiny_data, tmp_path, **kw)
    assert summary["steps"] == 6 and np.isfinite(summary["val"]["total"])

    out = tmp_path / "res.json"
    assert evaluate_main([str(tmp_path / "a"), "--data", str(tiny_data), "--split", "train", "--limit", "4",
                          "--resolution", "32", "--icp", "--out", str(out)]) == 0
    res = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"bare {c} in the JSON"))
    assert res["task"] == "image" and res["shapes"] == 4
    valued = [r for r in res["per_shape"] if r["chamfer_x1e3"] is not None]
    assert len(valued) + res["empty_outputs"] == 4       # 6 steps may decode nothing: counted, not inf
    for r in valued:
        assert 0 < r["chamfer_icp_x1e3"] <= r["chamfer_x1e3"]
        assert 0 <= r["fscore"] <= 1 and 0 <= r["fscore_icp"] <= 1     # every decoder gets an F-score
        if r["chamfer_icp_x1e3"] == r["chamfer_x1e3"]:                 # the alignment was not kept
            assert r["fscore_icp"] == r["fscore"]
    if valued:
        assert 0 <= res["fscore_category_mean"] <= 1
    assert table_main([str(out), str(out), "--icp", "--bootstrap", "100"]) == (0 if valued else 2)
    assert table_main([str(out), str(out), "--icp", "--fscore", "--bootstrap", "100"]) == (0 if valued else 2)


def test_image_augmentation_is_a_function_of_seed_and_step(tiny_data, tmp_path):
    t = Trainer(config(tiny_data, tmp_path / "a", task="image", arch="psg", encoder="lenet", encoder_width=4,
                       image_size=32))
    idx = t.batch_indices(0)
    x1 = t.task.inputs(t.cfg, t.train_set, idx, np.random.default_rng([0, 0, 1]))[0]
    x2 = t.task.inputs(t.cfg, t.train_set, idx, np.random.default_rng([0, 0, 1]))[0]
    x3 = t.task.inputs(t.cfg, t.train_set, idx, np.random.default_rng([0, 1, 1]))[0]
    fixed = t.task.inputs(t.cfg, t.train_set, idx, None)[0]
    assert torch.equal(x1, x2) and not torch.equal(x1, x3)
    assert torch.equal(fixed, t.task.inputs(t.cfg, t.train_set, idx, None)[0])
    assert x1.shape == (len(idx), 3, 32, 32)


def _teacher_and_student(data, tmp_path, teacher_iters: int, student_iters: int) -> tuple[Trainer, dict]:
    """An autoencoder run ``ae`` trained ``teacher_iters`` steps, and the settings of an image
    student regressed onto its codes."""
    teacher = Trainer(config(data, tmp_path / "ae", iters=teacher_iters))
    teacher.run()
    return teacher, dict(task="image", arch="aocnn", encoder="lenet", encoder_width=4, image_size=32,
                         iters=student_iters, teacher=str(tmp_path / "ae"))


def test_a_students_teacher_codes_are_kept_with_the_run_and_read_back_on_resume(tiny_data, tmp_path):
    teacher, kw = _teacher_and_student(tiny_data, tmp_path, 2, 2)
    first = Trainer(config(tiny_data, tmp_path / "img", **kw))
    kept = sorted((tmp_path / "img" / "teacher-codes").glob("*.pt"))
    assert [p.name.split("-")[0] for p in kept] == ["train", "val"]
    train_codes = torch.load(kept[0])
    assert torch.equal(train_codes, first.train_set.latents) and train_codes.shape == (len(first.train_set), 32)
    torch.save(torch.zeros_like(train_codes), kept[0])            # a resumed run reads them, not computes
    again = Trainer(config(tiny_data, tmp_path / "img", **kw))
    assert torch.equal(again.train_set.latents, torch.zeros_like(train_codes))
    assert torch.equal(again.val_set.latents, first.val_set.latents)
    # another teacher's weights are another key: its codes are computed afresh
    teacher.train_step()
    teacher.save()
    from model.train.tasks import _load_teacher
    _load_teacher.cache_clear()
    other = Trainer(config(tiny_data, tmp_path / "img", **kw))
    assert len(list((tmp_path / "img" / "teacher-codes").glob("*.pt"))) == 4
    assert not torch.equal(other.train_set.latents, first.train_set.latents)


def test_teacher_codes_interrupted_go_on_from_their_last_saved_part(tiny_data, tmp_path, monkeypatch):
    """The codes are saved in parts as they are made: a run stopped while making them keeps the
    parts it finished, and the next start computes only the rest, joining the same codes.  The
    work done is checked exactly (which parts were made, which read); the codes within float
    rounding, since parts of 8 shapes batch the encoder differently from parts of 512, and
    kernels may sum a batch in another order."""
    import model.train.tasks as tasks
    from export.parity import RELATIVE_TOLERANCE, relative_error

    _, kw = _teacher_and_student(tiny_data, tmp_path, 2, 2)
    whole = Trainer(config(tiny_data, tmp_path / "whole", **kw)).train_set.latents
    monkeypatch.setattr(tasks, "TEACHER_CODES_PART", 8)
    made, real, interrupt = [], tasks._codes_of, [True]

    class Stopped(Exception):
        pass

    def failing(model, spec, data, start, stop):
        if start >= 8 and interrupt.pop() if interrupt else False:
            raise Stopped                                          # stopped after the first part
        made.append((len(data), start))
        return real(model, spec, data, start, stop)

    monkeypatch.setattr(tasks, "_codes_of", failing)
    assert len(whole) > 16                                        # three parts
    with pytest.raises(Stopped):
        Trainer(config(tiny_data, tmp_path / "img", **kw))
    parts = sorted((tmp_path / "img" / "teacher-codes").glob("train-*/*.pt"))
    n = len(whole)
    assert [p.name for p in parts] == ["000000.pt"] and made == [(n, 0)]
    saved = torch.load(parts[0])
    resumed = Trainer(config(tiny_data, tmp_path / "img", **kw)).train_set.latents
    assert [m for m in made if m[0] == n] == [(n, 0), (n, 8), (n, 16)]  # the first part read, not made again
    assert relative_error(whole, resumed) <= RELATIVE_TOLERANCE                 # the same codes, to rounding
    assert torch.equal(resumed[:len(saved)], saved)                     # the saved part, read back as it was
    assert not list((tmp_path / "img" / "teacher-codes").glob("train-*/"))    # joined, parts removed


def test_image_encoder_regressed_onto_an_autoencoders_latents_uses_its_decoder(tiny_data, tmp_path):
    teacher, kw = _teacher_and_student(tiny_data, tmp_path, 3, 4)
    student = Trainer(config(tiny_data, tmp_path / "img", **kw))
    first = student.validate()["latent"]
    student.run()
    assert set(student.validate()) == {"latent", "total"} and student.validate()["latent"] < first
    dec_s, dec_t = student.model.decoder.state_dict(), teacher.model.decoder.state_dict()
    assert all(torch.equal(dec_s[k], dec_t[k]) for k in dec_t)          # frozen: still the teacher's
    # the targets are the teacher encoder's codes of each shape
    idx = np.arange(2)
    from model.nn.tensors import OctreeTensors
    octree, _ = student.train_set.batch(idx)
    with torch.no_grad():
        want = teacher.model.eval().encoder(OctreeTensors.from_octree(octree))
    assert torch.allclose(student.train_set.latents[:2], want, atol=1e-5)
    with pytest.raises(ValueError, match="channels"):
        Trainer(config(tiny_data, tmp_path / "bad", **{**kw, "channels": 8}))
    # the picture of real outputs: input, truth, the run, its depth colours; one row per category
    from research.figures import TILE, figure
    img = figure(str(tiny_data), [("student", str(tmp_path / "img"))], split="train", shapes=2)
    assert img.size == (4 * TILE, 18 + 2 * TILE)
    with pytest.raises(ValueError, match="one task"):
        figure(str(tiny_data), [("s", str(tmp_path / "img")), ("t", str(tmp_path / "ae"))], split="train")


def test_every_validated_step_keeps_its_weights_as_a_checkpoint_folder(tiny_data, tmp_path):
    """Trainer.snapshot: RUN/steps/<step>/ at each validation, in half precision, loadable as a
    checkpoint folder with the step and its validation losses; the final one is the run's weights."""
    from model.checkpoint import load_model

    trainer = Trainer(config(tiny_data, tmp_path / "run", iters=6, val_every=3, ckpt_every=2))
    trainer.run()
    assert sorted(p.name for p in (tmp_path / "run" / "steps").iterdir()) == ["000003", "000006"]
    val = {r["step"]: r for r in map(json.loads, (tmp_path / "run" / "metrics.jsonl").read_text().splitlines())
           if r["split"] == "val"}
    early, final = (load_model(tmp_path / "run" / "steps" / s) for s in ("000003", "000006"))
    assert (early.meta["steps"], final.meta["steps"]) == (3, 6)
    assert final.meta["validation"]["total"] == pytest.approx(val[6]["total"])
    assert final.meta["weights_dtype"] == "float16" and final.config.channels == 4
    trained = trainer.model.state_dict()
    for k, v in trained.items():
        assert torch.equal(final.model.state_dict()[k], v.half().to(v.dtype)), k
    assert not all(torch.equal(early.model.state_dict()[k], final.model.state_dict()[k]) for k in trained)
    # a kept step is calibrated and packaged like a run: the checkpoint chosen on the validation split
    from research.calibrate import calibrate
    from research.recipe import load_recipe
    from research.release import package

    report = calibrate(str(tmp_path / "run" / "steps" / "000003"), str(tiny_data), str(tmp_path / "cal"))
    calibrated = load_model(tmp_path / "cal")
    assert calibrated.meta["calibration"] == report and calibrated.meta["steps"] == 3
    moved = [k for k, v in calibrated.model.state_dict().items() if not torch.equal(v, early.model.state_dict()[k])]
    assert moved and all(k.startswith("decoder.pred.") and k.endswith(".bias") for k in moved)
    meta = package(tmp_path / "cal", tiny_data, tmp_path / "shipped", load_recipe("completion"), ["completion"],
                   by_recipe=False)
    assert meta["steps"] == 3 and meta["calibration"] == report
    shipped = load_model(tmp_path / "shipped").model.state_dict()
    assert all(torch.equal(shipped[k], v) for k, v in calibrated.model.state_dict().items())


