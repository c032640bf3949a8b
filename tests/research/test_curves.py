"""Training curves: metrics rows read per split (a resumed run's repeated steps counted once),
the moving average, the picture, the validation Chamfer distance of each kept step, and bad input
refused in one line."""

from __future__ import annotations

import json

import numpy as np
import pytest
from PIL import Image

from research.curves import log_scale, main, moving_average, read_curves


def _write_run(folder, rows) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "metrics.jsonl").write_text("".join(json.dumps(r) + "\n" for r in rows))


def _rows(scale: float, resumed: bool = False) -> list[dict]:
    train = [{"step": s, "split": "train", "lr": 1e-3, "seconds": 0.5 * s, "total": scale / s, "patch": 0.1}
             for s in range(10, 210, 10)]
    val = [{"step": s, "split": "val", "total": scale / s + 0.05, "patch": 0.12} for s in (100, 200)]
    if resumed:        # killed after step 150, resumed from the step-100 checkpoint: 110..150 logged twice,
        first = [dict(r, total=7.0) for r in train[10:15]]        # the new process's seconds from 0
        train = train[:10] + first + [dict(r, seconds=0.5 * (r["step"] - 100)) for r in train[10:]]
    return train + val


def test_rows_per_split_the_last_row_of_a_repeated_step_counts(tmp_path):
    _write_run(tmp_path / "a", _rows(2.0, resumed=True))
    c = read_curves(tmp_path / "a")
    assert c.steps["train"].tolist() == list(range(10, 210, 10)) and c.steps["val"].tolist() == [100, 200]
    assert c.values["train"]["total"][10:15] == pytest.approx([2.0 / s for s in range(110, 160, 10)])
    assert c.values["val"]["total"] == pytest.approx([0.07, 0.06])
    assert c.seconds == 75.0 + 50.0                   # both processes' wall time: to step 150, then 100 -> 200
    assert sorted(c.terms("val")) == ["patch", "total"]


def test_a_panel_spanning_more_than_ten_times_is_drawn_on_a_log_scale():
    nan = float("nan")
    assert log_scale([np.array([16.0, 2.3]), np.array([0.45, 0.5, nan])])       # an image run beside an autoencoder
    assert not log_scale([np.array([1.7, 0.45]), np.array([0.39, 0.22])])          # 7.7x: linear
    assert not log_scale([np.array([3.0, -1.0, 40.0])])                            # a loss below zero
    assert not log_scale([np.array([0.0, 5.0])]) and not log_scale([np.array([nan])]) and not log_scale([])


def test_moving_average_of_the_rows_before_each_skipping_gaps():
    v = np.array([1.0, 2.0, np.nan, 4.0, 5.0])
    assert moving_average(v, 2) == pytest.approx([1.0, 1.5, 2.0, 4.0, 4.5])
    assert moving_average(v, 1)[2] != moving_average(v, 1)[2]          # NaN alone stays NaN
    assert moving_average(v, 10) == pytest.approx([1.0, 1.5, 1.5, 7 / 3, 3.0])


def test_the_picture_has_a_panel_per_term_and_bad_input_exits_2(tmp_path, capsys):
    _write_run(tmp_path / "a", _rows(2.0))
    _write_run(tmp_path / "b", _rows(4.0))
    out = tmp_path / "curves.png"
    assert main([str(tmp_path / "a"), str(tmp_path / "b"), "--labels", "A", "B", "--out", str(out)]) == 0
    assert "total, patch of 2 run(s)" in capsys.readouterr().out
    two = Image.open(out)
    assert main([str(tmp_path / "a"), "--terms", "total", "--out", str(tmp_path / "one.png")]) == 0
    one = Image.open(tmp_path / "one.png")
    assert two.width > 1.8 * one.width and two.height == one.height
    assert np.asarray(one.convert("L")).std() > 5                     # lines drawn, not a blank page
    for args, needle in (([str(tmp_path / "nothing")], "no metrics.jsonl"),
                         ([str(tmp_path / "a"), "--terms", "iou"], "no run logged iou"),
                         ([str(tmp_path / "a"), "--labels", "x", "y"], "2 names for 1 runs"),
                         ([str(tmp_path / "a"), "--window", "0"], "at least 1")):
        assert main([*args, "--out", str(tmp_path / "bad.png")]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1
        assert not (tmp_path / "bad.png").exists()
    (tmp_path / "c").mkdir()
    (tmp_path / "c" / "metrics.jsonl").write_text('{"step": 1}\n')
    assert main([str(tmp_path / "c"), "--out", str(tmp_path / "bad.png")]) == 2
    assert "metrics.jsonl:1: not a metrics row" in capsys.readouterr().err


def test_chamfer_measures_each_kept_step_once_and_names_the_lowest(tiny_data, tmp_path, capsys, monkeypatch):
    """--chamfer: every validated step's weights measured on the validation split's first shapes of
    each category, as research.evaluate measures them; kept beside the weights and reused while the
    settings are the same; a panel of its own; the step with the lowest figure named."""
    from model.train.loop import TrainConfig, Trainer
    from research.evaluate import EvalOptions, evaluate

    run = tmp_path / "run"
    Trainer(TrainConfig(data=str(tiny_data), depth=5, arch="aocnn", out=str(run), iters=16, batch_size=4,
                        val_every=8, ckpt_every=8, latent=32, channels=4, progress=False)).run()
    args = [str(run), "--chamfer", str(tiny_data), "--per-category", "1", "--resolution", "16"]
    assert main([str(run), "--out", str(tmp_path / "loss.png")]) == 0           # the loss terms alone
    capsys.readouterr()
    assert main([*args, "--out", str(tmp_path / "c.png")]) == 0
    printed = capsys.readouterr().out
    kept = {s: json.loads((run / "steps" / s / "chamfer.json").read_text()) for s in ("000008", "000016")}
    records = json.loads((tiny_data / "manifest.json").read_text())["records"]
    categories = len({r["category"] for r in records if r["split"] == "val"})
    for name, figure in kept.items():
        direct = evaluate(str(run / "steps" / name), str(tiny_data), EvalOptions("val", 16, per_category=1))
        assert figure["chamfer_x1e3"] == pytest.approx(direct["chamfer_x1e3_category_mean"])
        assert figure["shapes"] == direct["shapes"] == categories and figure["step"] == int(name)
        assert figure["chamfer_x1e3"] is not None and figure["empty_outputs"] == 0
    best = min((8, 16), key=lambda s: kept[f"{s:06d}"]["chamfer_x1e3"])
    assert f"lowest at step {best}" in printed and "chamfer_x1e3" in printed
    panels = len(read_curves(run).terms("val"))
    ratio = Image.open(tmp_path / "c.png").width / Image.open(tmp_path / "loss.png").width
    assert ratio == pytest.approx((panels + 1) / panels, rel=0.05)                # one more panel: the Chamfer's
    calls = []
    monkeypatch.setattr("research.curves.evaluate", lambda *a, **k: calls.append(a) or evaluate(*a, **k))
    assert main([*args, "--out", str(tmp_path / "again.png")]) == 0 and calls == []   # reused, not measured again
    assert main([*args[:-1], "32", "--out", str(tmp_path / "finer.png")]) == 0      # new settings: measured again
    assert len(calls) == 2
    assert json.loads((run / "steps" / "000008" / "chamfer.json").read_text())["settings"]["resolution"] == 32
    for bad, needle in (([str(run), "--chamfer", str(tmp_path)], "no manifest.json"),
                        ([*args[:4], "0"], "--per-category must be at least 1")):
        assert main([*bad, "--out", str(tmp_path / "bad.png")]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1 and not (tmp_path / "bad.png").exists()
