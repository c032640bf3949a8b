"""Training off the training process: batches prepared by loader processes, the device option,
mixed precision, and datasets read by several processes."""

import json

import numpy as np
import pytest
import torch

from model.train.data import RecordSet
from model.train.loop import Trainer

from .test_train import config


def test_loader_processes_give_the_weights_and_validation_of_one_process(tiny_data, tmp_path):
    runs = {}
    for workers in (0, 2):
        trainer = Trainer(config(tiny_data, tmp_path / str(workers), iters=6, val_every=3, loader_workers=workers))
        trainer.run()
        runs[workers] = (trainer.model.state_dict(),
                         [json.loads(l) for l in (tmp_path / str(workers) / "metrics.jsonl").read_text().splitlines()])
    (a, rows_a), (b, rows_b) = runs[0], runs[2]
    assert all(torch.equal(a[k], b[k]) for k in a)
    val = [r for r in rows_a if r["split"] == "val"]
    assert len(val) == 2 and val == [r for r in rows_b if r["split"] == "val"]


def test_mixed_precision_trains_close_to_float32(tiny_data, tmp_path):
    losses = {}
    for amp in (False, True):
        trainer = Trainer(config(tiny_data, tmp_path / str(amp), amp=amp))
        losses[amp] = [trainer.train_step()["total"] for _ in range(3)]
        assert np.isfinite(trainer.validate()["total"])
    assert losses[True][0] == pytest.approx(losses[False][0], rel=0.05)   # the same batch, bfloat16 forward
    assert losses[True] != losses[False]


@pytest.mark.parametrize("device, needle", [
    ("meta", "training runs on cpu or cuda"),
    ("tpu", "is not a device"),
    ("gpu0", "is not a device"),
    ("cuda", "sees no CUDA GPU"),
])
def test_an_unusable_device_is_refused_in_one_line(tiny_data, tmp_path, capsys, monkeypatch, device, needle):
    from model.train.__main__ import main

    monkeypatch.setattr(torch.cuda, "is_available", lambda: False)
    code = main(["autoencoder", "--data", str(tiny_data), "--depth", "5", "--out", str(tmp_path / "r"),
                 "--quiet", "--device", device])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and needle in err[0]
    assert not (tmp_path / "r").exists()


def test_a_dataset_read_by_several_processes_equals_one_read_by_one(tiny_data):
    one = RecordSet(tiny_data, "train", images=True, seed=3)
    two = RecordSet(tiny_data, "train", images=True, seed=3, workers=2)
    assert [s.shape_id for s in one.samples] == [s.shape_id for s in two.samples]
    for a, b in zip(one.samples, two.samples):
        assert np.array_equal(a.points, b.points) and np.array_equal(a.images, b.images)
        assert all(np.array_equal(x.key, y.key) and np.array_equal(x.plane, y.plane)
                   for x, y in zip(a.octree.levels, b.octree.levels))
