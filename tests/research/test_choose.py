"""Choosing a run's checkpoint on the validation split: the kept step with the lowest validation
Chamfer distance, copied to a checkpoint folder every command reads; bad input refused in one line."""

from __future__ import annotations

import json
import math

import pytest
import torch

from research.choose import choose, main
from research.curves import lowest_step


def test_lowest_step_skips_empty_outputs_and_takes_the_earlier_on_a_tie():
    assert lowest_step({1000: 0.5, 2000: 0.4, 3000: 0.45}) == 2000
    assert lowest_step({3000: 0.4, 1000: 0.4, 2000: math.nan}) == 1000
    assert lowest_step({1000: math.nan, 2000: 0.9}) == 2000
    for figures in ({}, {1000: math.nan}):
        with pytest.raises(ValueError, match="no kept step"):
            lowest_step(figures)


def test_the_kept_step_with_the_lowest_figure_is_copied_and_loads_as_a_run(tiny_data, tmp_path, capsys):
    from model.train.config import read_run
    from model.train.loop import TrainConfig, Trainer

    run, out = tmp_path / "run", tmp_path / "best"
    Trainer(TrainConfig(data=str(tiny_data), depth=5, arch="aocnn", out=str(run), iters=16, batch_size=4,
                        val_every=8, ckpt_every=8, latent=32, channels=4, progress=False)).run()
    args = [str(run), "--data", str(tiny_data), "--out", str(out), "--per-category", "1", "--resolution", "16"]
    assert main(args) == 0
    kept = {s: json.loads((run / "steps" / f"{s:06d}" / "chamfer.json").read_text())["chamfer_x1e3"]
            for s in (8, 16)}
    best = min(kept, key=lambda s: (kept[s], s))
    assert f"step {best} of" in capsys.readouterr().out

    def chosen_weights_are(step: int) -> None:
        source = run / "steps" / f"{step:06d}"
        assert (out / "model.pt").read_bytes() == (source / "model.pt").read_bytes()
        meta = json.loads((out / "model.json").read_text())
        assert meta["steps"] == step and meta["chosen"]["per_category"] == 1
        assert meta["chosen"]["chamfer_x1e3"] == {str(k): pytest.approx(v) for k, v in kept.items()}
        loaded, original = read_run(out), read_run(source)
        assert loaded.config == original.config
        assert all(torch.equal(loaded.weights[k], v) for k, v in original.weights.items())

    chosen_weights_are(best)
    # the figures decide: make the other step's (kept) figure the lowest and choose again
    other = 24 - best
    cached = run / "steps" / f"{other:06d}" / "chamfer.json"
    figure = json.loads(cached.read_text())
    cached.write_text(json.dumps({**figure, "chamfer_x1e3": kept[best] / 2}))
    kept[other] = kept[best] / 2
    assert choose(run, tiny_data, out, per_category=1, resolution=16).step == other
    chosen_weights_are(other)


def test_bad_input_exits_2_in_one_line_and_writes_nothing(tiny_data, tmp_path, capsys):
    run = tmp_path / "run"
    (run / "steps").mkdir(parents=True)
    for args, needle in (([str(tmp_path / "none")], "no steps/ folder"),
                         ([str(run)], "no kept step"),
                         ([str(run), "--per-category", "0"], "--per-category must be at least 1")):
        assert main([*args, "--data", str(tiny_data), "--out", str(tmp_path / "best")]) == 2
        err = capsys.readouterr().err
        assert needle in err and err.count("\n") == 1 and not (tmp_path / "best").exists()
    assert main([str(run), "--data", str(tiny_data), "--out", str(run / "best")]) == 2
    assert "inside the run" in capsys.readouterr().err
