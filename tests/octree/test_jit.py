"""The kernels' disk cache on an install that cannot write beside its sources."""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
PROBE = ("import os; real = os.access; "
         "os.access = (lambda p, m: False if {readonly} and 'octree' in str(p) and m == os.W_OK else real(p, m)); "
         "from numba.core import config; import model.octree.jit; print(repr(config.CACHE_DIR))")


def cache_dir(readonly: bool, env_dir: str | None) -> str:
    env = {k: v for k, v in os.environ.items() if k != "NUMBA_CACHE_DIR"}
    if env_dir is not None:
        env["NUMBA_CACHE_DIR"] = env_dir
    out = subprocess.run([sys.executable, "-c", PROBE.format(readonly=readonly)], capture_output=True, text=True,
                         cwd=REPO, env=env, timeout=120)
    assert out.returncode == 0, out.stderr[-1500:]
    return eval(out.stdout.strip().splitlines()[-1])


def test_a_read_only_install_caches_in_the_temporary_directory():
    assert cache_dir(True, None) == os.path.join(tempfile.gettempdir(), f"aocnn-numba-{os.getuid()}")


def test_a_writable_install_and_a_chosen_folder_are_left_alone():
    assert cache_dir(False, None) == ""
    assert cache_dir(True, "/somewhere/else") == "/somewhere/else"
