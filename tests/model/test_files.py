"""The atomic-write helper: readers see the old file or the whole new one, never a part; no
temporary file survives a failure; the mode follows the umask like a plain open()."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

from model.files import TEMP_PREFIX, atomic_path, write_atomic


def test_a_failure_mid_write_keeps_the_previous_file_and_leaves_no_temporary(tmp_path):
    target = tmp_path / "result.json"
    write_atomic(target, b"old contents")
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            with open(tmp, "wb") as fh:
                fh.write(b"half of the new")
            assert os.path.exists(tmp) and target.read_bytes() == b"old contents"   # not in place yet
            raise RuntimeError("killed mid-write")
    assert target.read_bytes() == b"old contents"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["result.json"]
    with pytest.raises(TypeError):
        write_atomic(target, "not bytes")                         # fails inside the write itself
    assert target.read_bytes() == b"old contents"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(TEMP_PREFIX)]
    write_atomic(target, b"new contents")
    assert target.read_bytes() == b"new contents"


@pytest.mark.parametrize("umask, mode", [(0o022, 0o644), (0o027, 0o640), (0o002, 0o664)])
def test_the_mode_follows_the_umask(tmp_path, umask, mode):
    target = tmp_path / "out.bin"
    code = (f"import os; os.umask({umask}); from model.files import write_atomic; "
            f"write_atomic({str(target)!r}, b'x')")
    subprocess.run([sys.executable, "-c", code], check=True, timeout=60)
    assert target.stat().st_mode & 0o777 == mode


def test_npz_bytes_round_trip_and_depend_on_the_arrays_alone(monkeypatch):
    import io
    import time
    import zipfile

    import numpy as np

    from model.files import npz_bytes

    arrays = {"points": np.random.default_rng(0).random((500, 3)).astype(np.float32),
              "plane": np.array([[np.nan, 1.0]]), "label": np.arange(7, dtype=np.int8),
              "category": np.array("chair"), "version": np.array(1), "empty": np.zeros((0, 3))}
    data = npz_bytes(arrays)
    with np.load(io.BytesIO(data)) as f:
        assert f.files == list(arrays)
        for k, v in arrays.items():
            assert f[k].dtype == v.dtype and f[k].shape == v.shape
            assert np.array_equal(f[k], v, equal_nan=v.dtype.kind == "f")
    assert all(i.compress_type == zipfile.ZIP_DEFLATED for i in zipfile.ZipFile(io.BytesIO(data)).infolist())
    # written a day later, the same bytes (np.savez stamps each member with the time of writing)
    later = time.time() + 86_400
    monkeypatch.setattr(time, "time", lambda: later)
    assert npz_bytes(arrays) == data
    assert npz_bytes({**arrays, "label": arrays["label"] + 1}) != data
    # a stronger level: smaller here, the same arrays
    assert len(npz_bytes(arrays, level=9)) < len(data)
    with pytest.raises(ValueError, match="pickle"):
        npz_bytes({"objects": np.array([{"a": 1}], dtype=object)})
