"""Joining one model's results on several splits: the measures are those of all the shapes at
once, not the mean of the splits' means."""

import json

import pytest

from research.results import join_results
from research.results_table import main

from .test_results_table import results


def split_result(values: dict[str, list[float | None]], split: str, **settings) -> dict:
    """An evaluation result of ``split`` (shape ids prefixed by it; None: an empty output)."""
    r = results({c: [v for v in vs if v is not None] for c, vs in values.items()})
    r["per_shape"] = [{"category": c, "shape_id": f"{split}_{c}_{i}", "chamfer_x1e3": v, "truth_nodes": 10}
                      for c, vs in values.items() for i, v in enumerate(vs)]
    r.update(run="runs/x", task="completion", split=split, shapes=len(r["per_shape"]),
             empty_outputs=sum(v is None for vs in values.values() for v in vs), **settings)
    return r


def test_the_joined_measures_are_those_of_all_shapes_at_once():
    a = split_result({"chair": [1.0, 3.0], "table": [2.0]}, "test")
    b = split_result({"chair": [5.0, None], "lamp": [4.0]}, "val")
    a["octree"], b["octree"] = {"truth_nodes": 10.0, "decoded_nodes": 6.0}, {"truth_nodes": 40.0, "decoded_nodes": 9.0}
    j = join_results([a, b])
    assert j["chamfer_x1e3"] == {"chair": 3.0, "lamp": 4.0, "table": 2.0}       # (1 + 3 + 5) / 3: the empty one left out
    assert j["chamfer_x1e3_category_mean"] == pytest.approx(3.0)                 # the splits' means would give 3.25
    assert (j["shapes"], j["empty_outputs"], len(j["per_shape"]), j["split"]) == (6, 1, 6, "test+val")
    assert j["octree"]["truth_nodes"] == pytest.approx((10 * 3 + 40 * 3) / 6)
    a["watertight_crossing"] = 2                                    # counted in one split, not in the other
    assert "watertight_crossing" not in join_results([a, b]) and "watertight_crossing" not in join_results([b, a])
    b["watertight_crossing"] = 1
    assert join_results([a, b])["watertight_crossing"] == 3


def test_results_that_differ_or_overlap_are_not_joined():
    a = split_result({"chair": [1.0]}, "test", symmetry=0.85)
    with pytest.raises(ValueError, match="differ in symmetry"):
        join_results([a, split_result({"chair": [1.0]}, "val")])
    with pytest.raises(ValueError, match="share shapes"):
        join_results([a, split_result({"chair": [2.0]}, "test", symmetry=0.85)])
    with pytest.raises(ValueError, match="nothing"):
        join_results([])


def test_the_command_pairs_joined_results(tmp_path, capsys):
    files = {}
    for name, shift in (("base", 0.0), ("other", 0.5)):
        for split, vals in (("test", [1.0, 2.0]), ("val", [3.0])):
            files[name, split] = tmp_path / f"{name}_{split}.json"
            files[name, split].write_text(json.dumps(split_result({"car": [v + shift for v in vals]}, split)))
    joined = [f"{files[n, 'test']}+{files[n, 'val']}" for n in ("base", "other")]
    assert main([*joined, "--bootstrap", "200"]) == 0
    out = capsys.readouterr().out
    assert "| other_test+other_val | +0.500 | [+0.500, +0.500] | 3 / 0 / 0 | 3 |" in out
    assert "**2.000**" in out and "**2.500**" in out                               # (1 + 2 + 3) / 3, shifted
    assert main([f"{files['base', 'test']}+{files['base', 'test']}"]) == 2
    assert "share shapes" in capsys.readouterr().err


def test_photo_results_join_with_their_mask_sources_added():
    photos = {"kind": "photos", "remove_background": "auto", "foreground_network": True}
    a = split_result({"chair": [1.0]}, "test", input={**photos, "mask_sources": {"network": 2, "alpha": 1}})
    b = split_result({"chair": [2.0]}, "val", input={**photos, "mask_sources": {"network": 4}})
    assert join_results([a, b])["input"] == {**photos, "mask_sources": {"alpha": 1, "network": 6}}
    c = split_result({"chair": [2.0]}, "val", input={**photos, "remove_background": "false", "mask_sources": {}})
    with pytest.raises(ValueError, match="differ in input"):
        join_results([a, c])
