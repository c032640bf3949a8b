"""research.evaluate: which shapes a partial evaluation takes."""

import json

from model.train.loop import Trainer

from ..model.test_train import config


def test_evaluate_per_category_takes_the_first_shapes_of_each_category(tiny_data, tmp_path):
    from research.evaluate import main as evaluate_main
    from research.measures import first_of_each

    assert first_of_each(["a", "a", "b", "a", "c", "b", "b"], 2).tolist() == [0, 1, 2, 4, 5]
    assert first_of_each(["a", "b"], 1).tolist() == [0, 1] and first_of_each([], 3).tolist() == []
    Trainer(config(tiny_data, tmp_path / "run", iters=2)).run()
    out = tmp_path / "e.json"
    assert evaluate_main([str(tmp_path / "run"), "--data", str(tiny_data), "--split", "train", "--per-category", "1",
                          "--resolution", "16", "--out", str(out)]) == 0
    res = json.loads(out.read_text())
    rows = json.loads((tiny_data / "manifest.json").read_text())["records"]
    train = [r for r in rows if r["split"] == "train"]
    firsts = [next(r["shape_id"] for r in train if r["category"] == c) for c in ("airplane", "chair", "table")]
    assert res["per_category"] == 1 and sorted(r["shape_id"] for r in res["per_shape"]) == sorted(firsts)
    assert evaluate_main([str(tmp_path / "run"), "--data", str(tiny_data), "--per-category", "0",
                          "--out", str(out)]) == 2
