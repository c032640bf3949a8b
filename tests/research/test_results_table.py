"""Comparing evaluation results: the table and the paired, stratified bootstrap."""

import gzip
import json

import numpy as np
import pytest

from research.results_table import main, markdown_table, paired_difference


def results(values: dict[str, list[float]], arch="aocnn") -> dict:
    rows = [{"category": c, "shape_id": f"{c}_{i}", "chamfer_x1e3": v, "truth_nodes": 10}
            for c, vs in values.items() for i, v in enumerate(vs)]
    means = {c: float(np.mean(v)) for c, v in values.items()}
    return {"arch": arch, "per_shape": rows, "chamfer_x1e3": means,
            "chamfer_x1e3_category_mean": float(np.mean(list(means.values()))),
            "octree": {"decoded_nodes": 5.0, "truth_nodes": 10.0}}


def test_paired_difference_is_the_difference_of_category_means_with_a_covering_interval():
    rng = np.random.default_rng(0)
    base = {"a": list(rng.random(30)), "b": list(rng.random(10) + 2)}
    shift = {"a": [v + 0.5 for v in base["a"]], "b": [v - 0.1 for v in base["b"]]}
    d = paired_difference(results(base), results(shift), draws=2000)
    assert d.mean == pytest.approx((0.5 - 0.1) / 2)
    assert d.low == pytest.approx(0.2) and d.high == pytest.approx(0.2)   # constant shifts: no spread
    assert (d.base_wins, d.other_wins, d.ties, d.shapes) == (30, 10, 0, 40)
    noisy = {"a": [v + rng.normal(0, 0.3) for v in base["a"]], "b": base["b"]}
    n = paired_difference(results(base), results(noisy), draws=4000)
    assert n.low < n.mean < n.high and n.high - n.low > 0.05


def test_ties_are_counted_apart_from_wins():
    base = {"a": [1.0, 2.0, 3.0, 4.0]}
    other = {"a": [1.0, 2.5, 2.0, 4.0]}                  # equal, worse, better, equal
    d = paired_difference(results(base), results(other), draws=200)
    assert (d.base_wins, d.other_wins, d.ties, d.shapes) == (1, 1, 2, 4)


def test_table_and_command(tmp_path, capsys):
    a, b = results({"chair": [1.0, 2.0]}), results({"chair": [1.5, 2.5]}, arch="psg")
    assert "**1.500**" in markdown_table([a], ["x"])
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(a))
    pb.write_text(json.dumps(b))
    assert main([str(pa), str(pb), "--bootstrap", "200"]) == 0
    out = capsys.readouterr().out
    assert "| b | +0.500 | [+0.500, +0.500] | 2 / 0 / 0 | 2 |" in out
    pz = tmp_path / "b.json.gz"                          # as kept in docs/results
    pz.write_bytes(gzip.compress(json.dumps(b).encode()))
    assert main([str(pa), str(pz), "--bootstrap", "200"]) == 0
    assert "| b | +0.500 | [+0.500, +0.500] | 2 / 0 / 0 | 2 |" in capsys.readouterr().out
    pb.write_text("{}")
    assert main([str(pa), str(pb)]) == 2
    assert "no per-shape rows" in capsys.readouterr().err
    pz.write_bytes(b"\x1f\x8b not gzip")
    assert main([str(pa), str(pz)]) == 2
    assert "not a readable results file" in capsys.readouterr().err


def test_completion_tables_end_with_the_partial_input_and_compare_the_missing_part(tmp_path, capsys):
    a = results({"car": [1.0, 3.0]})
    a.update(input_chamfer_x1e3={"car": 0.25}, input_chamfer_x1e3_category_mean=0.25,
             missing_x1e3={"car": 2.0}, missing_x1e3_category_mean=2.0,
             input_missing_x1e3={"car": 9.0}, input_missing_x1e3_category_mean=9.0)
    for r, v in zip(a["per_shape"], (1.0, 3.0)):
        r["missing_x1e3"] = v
    lines = markdown_table([a], ["aocnn"]).splitlines()
    assert lines[-1].startswith("| the partial input itself | 0.25 | **0.250**")
    assert markdown_table([a], ["aocnn"], "missing_x1e3").splitlines()[-1].startswith(
        "| the partial input itself | 9.00 | **9.000**")
    b = json.loads(json.dumps(a))
    for r in b["per_shape"]:
        r["missing_x1e3"] += 0.5
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(a))
    pb.write_text(json.dumps(b))
    assert main([str(pa), str(pb), "--missing", "--bootstrap", "200"]) == 0
    assert "| b | +0.500 | [+0.500, +0.500] | 2 / 0 / 0 | 2 |" in capsys.readouterr().out
    assert main([str(pa), str(pb), "--missing", "--icp"]) == 2


def test_surfaces_compares_the_closed_mesh_with_the_patches_inside_each_result(tmp_path, capsys):
    a = results({"car": [1.0, 3.0], "chair": [2.0, 2.0]})
    closed = {"car_0": 1.5, "car_1": 3.0, "chair_0": 2.0, "chair_1": 1.0}
    for r in a["per_shape"]:
        r.update(patches_area_chamfer_x1e3=r["chamfer_x1e3"], watertight_chamfer_x1e3=closed[r["shape_id"]])
    a.update(patches_area_chamfer_x1e3_category_mean=2.0, watertight_chamfer_x1e3_category_mean=1.875,
             patches_area_fscore_category_mean=0.5, watertight_fscore_category_mean=0.4, watertight_not_closed=0)
    pa = tmp_path / "a.json"
    pa.write_text(json.dumps(a))
    assert main([str(pa), "--surfaces", "--bootstrap", "200"]) == 0
    row = capsys.readouterr().out.splitlines()[-1]
    # car: +0.5 and 0; chair: 0 and -1 -> category means +0.25 and -0.5 -> -0.125
    assert row.startswith("| a | 2.000 | 1.875 | -0.125 | [")
    assert "| 1 / 1 / 2 | 0.500 / 0.400 | 0 | - | 4 |" in row                # measured before crossings were
    for r, share in zip(a["per_shape"], (0.0, 0.25, 0.125, 0.0)):
        r["watertight_crossing_share"] = share
    pa.write_text(json.dumps(a))
    assert main([str(pa), "--surfaces", "--bootstrap", "200"]) == 0
    assert "| 0 | 2 (6.2%) | 4 |" in capsys.readouterr().out.splitlines()[-1]    # 2 cross; median of 0, 0, .125, .25
    del a["per_shape"][0]["watertight_crossing_share"]                         # a result joined with an older one
    pa.write_text(json.dumps(a))
    assert main([str(pa), "--surfaces", "--bootstrap", "200"]) == 0
    assert "| 0 | 2 of 3 measured (12.5%) | 4 |" in capsys.readouterr().out.splitlines()[-1]
    plain = results({"car": [1.0]})
    pa.write_text(json.dumps(plain))
    assert main([str(pa), "--surfaces"]) == 2
    assert "no closed-surface figures" in capsys.readouterr().err
    assert main([str(pa), "--surfaces", "--icp"]) == 2


def mask_results(values: dict[str, list[float]]) -> dict:
    """A foreground evaluation's JSON: per-shape mask IoU and its summaries."""
    rows = [{"category": c, "shape_id": f"{c}_{i}", "mask_iou": v}
            for c, vs in values.items() for i, v in enumerate(vs)]
    every = np.array([r["mask_iou"] for r in rows])
    means = {c: float(np.mean(v)) for c, v in values.items()}
    return {"task": "foreground", "per_shape": rows, "shapes": len(rows), "mask_iou": means,
            "mask_iou_category_mean": float(np.mean(list(means.values()))),
            "mask_iou_median": float(np.median(every)), "mask_iou_above_0.9": float((every > 0.9).mean())}


def test_foreground_results_are_compared_by_mask_iou_where_higher_wins(tmp_path, capsys):
    base = mask_results({"chair": [0.5, 0.95, 0.8], "lamp": [0.2]})
    other = mask_results({"chair": [0.7, 0.91, 0.8], "lamp": [0.6]})      # better, worse, equal; better
    other["thin_recall_category_mean"] = 0.8125                              # measured for b only
    d = paired_difference(base, other, draws=200, metric="mask_iou", higher_is_better=True)
    assert d.mean == pytest.approx(((0.2 - 0.04) / 3 + 0.4) / 2)
    assert (d.base_wins, d.other_wins, d.ties, d.shapes) == (1, 2, 1, 4)
    pa, pb, pc = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "c.json"
    pa.write_text(json.dumps(base))
    pb.write_text(json.dumps(other))
    assert main([str(pa), str(pb), "--bootstrap", "200"]) == 0
    out = capsys.readouterr().out
    assert "| a | 0.750 | 0.200 | **0.475** | 0.650 | 25% | — | 4 |" in out
    assert "| b | 0.803 | 0.600 | **0.702** | 0.750 | 25% | 0.812 | 4 |" in out
    assert "mask IoU category mean" in out and "| b | +0.227 |" in out and "| 1 / 2 / 1 | 4 |" in out
    assert main([str(pa), str(pb), "--icp"]) == 2
    assert "not the foreground network's masks" in capsys.readouterr().err
    pc.write_text(json.dumps(results({"chair": [1.0]})))
    assert main([str(pa), str(pc)]) == 2
    assert "only be compared with foreground results" in capsys.readouterr().err


def test_fscore_compares_the_f_score_where_higher_wins_and_needs_results_that_hold_it(tmp_path, capsys):
    a, b = results({"car": [1.0, 2.0]}), results({"car": [3.0, 4.0]}, arch="atlasnet")
    for r, served, aligned in zip(a["per_shape"] + b["per_shape"], (0.6, 0.2, 0.5, 0.3), (0.7, 0.2, 0.5, 0.4)):
        r.update(fscore=served, fscore_icp=aligned)
    a.update(fscore={"car": 0.4}, fscore_category_mean=0.4, fscore_icp={"car": 0.45}, fscore_icp_category_mean=0.45)
    b.update(fscore={"car": 0.4}, fscore_category_mean=0.4, fscore_icp={"car": 0.45}, fscore_icp_category_mean=0.45)
    pa, pb = tmp_path / "a.json", tmp_path / "b.json"
    pa.write_text(json.dumps(a))
    pb.write_text(json.dumps(b))
    assert main([str(pa), str(pb), "--fscore", "--bootstrap", "200"]) == 0
    out = capsys.readouterr().out
    # per shape b - a: -0.1 and +0.1: one win each, though b is worse by Chamfer on both
    assert "| a | 0.400 | **0.400** |" in out and "F-score at 1% of the diagonal category mean" in out
    assert "| b | +0.000 |" in out and "| 1 / 1 / 0 | 2 |" in out
    assert main([str(pa), str(pb), "--fscore", "--icp", "--bootstrap", "200"]) == 0
    out = capsys.readouterr().out
    # after ICP: -0.2 and +0.2; a higher F-score on b's second shape counts as b's win
    assert "F-score at 1% of the diagonal after ICP" in out and "| b | +0.000 | [-0.200, +0.200] | 1 / 1 / 0 | 2 |" in out
    assert main([str(pa), str(pb), "--fscore", "--missing"]) == 2
    old = results({"car": [1.0, 2.0]})                    # evaluated before every output had an F-score
    pb.write_text(json.dumps(old))
    assert main([str(pa), str(pb), "--fscore"]) == 2
    assert "has no fscore: evaluate it again" in capsys.readouterr().err
