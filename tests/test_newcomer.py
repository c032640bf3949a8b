"""Defects a new user met following the README: file modes, depth colours, empty outputs."""

import json
import os
import warnings

import numpy as np

from model.files import UMASK, atomic_path, write_atomic
from model.octree.patches import DEPTH_COLORS
from research.results_table import main as table_main


def test_atomic_files_get_the_umask_mode_not_0600(tmp_path):
    write_atomic(tmp_path / "a.json", b"{}")
    with atomic_path(tmp_path / "b.bin") as tmp:
        with open(tmp, "wb") as fh:
            fh.write(b"x")
    for name in ("a.json", "b.bin"):
        mode = os.stat(tmp_path / name).st_mode & 0o777
        assert mode == 0o666 & ~UMASK and mode & 0o044 == 0o044 & ~UMASK


def test_neighbouring_depths_have_clearly_different_colours():
    c = DEPTH_COLORS[3:11].astype(float)
    dist = np.linalg.norm(c[:, None] - c[None], axis=2) + np.eye(len(c)) * 1e9
    assert dist.min() > 60                      # the old palette: ~25 between depths 4 and 7


def _result(path, values):
    rows = [{"category": "chair", "shape_id": f"s{i}", "chamfer_x1e3": v, "truth_nodes": 10}
            for i, v in enumerate(values)]
    valid = [v for v in values if v is not None]
    res = {"per_shape": rows, "chamfer_x1e3": {"chair": float(np.mean(valid))} if valid else {},
           "chamfer_x1e3_category_mean": float(np.mean(valid)) if valid else None,
           "empty_outputs": values.count(None), "octree": {"decoded_nodes": None, "truth_nodes": 10.0}}
    path.write_text(json.dumps(res, allow_nan=False))
    return path


def test_results_table_with_empty_outputs_has_no_nan_and_no_warning(tmp_path, capsys):
    a = _result(tmp_path / "a.json", [1.0, None, 2.0, 3.0])
    b = _result(tmp_path / "b.json", [None, 1.5, 2.5, 3.5])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert table_main([str(a), str(b), "--bootstrap", "200"]) == 0
    out = capsys.readouterr().out
    assert "nan" not in out.lower() and "inf" not in out.lower()
    assert "| b | +0.500 | [+0.500, +0.500] | 2 / 0 / 0 | 2 |" in out      # only the shapes both decoded
    assert "| a | 2.00 | **2.000** | 1 |" in out                        # the empty output is counted


def test_json_outputs_are_strict_even_with_nan_and_inf():
    from model.files import json_text

    text = json_text({"loss": float("nan"), "best": np.float32(np.inf), "ok": [np.float64(1.5), 2]})
    assert json.loads(text, parse_constant=lambda c: (_ for _ in ()).throw(ValueError(c))) == \
        {"loss": None, "best": None, "ok": [1.5, 2]}
