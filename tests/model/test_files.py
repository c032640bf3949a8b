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
