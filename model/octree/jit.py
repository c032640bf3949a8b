"""How the octree's kernels are compiled: numba, machine code cached on disk, the GIL released.

numba keeps the machine code beside the sources (``__pycache__``) or in the user's cache; an
install that can write neither (a Docker image run as an unprivileged user with no home, a
read-only site-packages) would fail at import.  Such an install caches in a per-user folder of the
system's temporary directory instead, unless ``NUMBA_CACHE_DIR`` says where; that folder starts as
a copy of ``AOCNN_NUMBA_SEED`` where it names one (kernels compiled when an image was built, with
``NUMBA_CACHE_DIR`` pointing there: numba loads them where the CPU is the build machine's, and
compiles afresh elsewhere).
"""

from __future__ import annotations

import os
import shutil
import tempfile

import numba
from numba.core import config


def _writable(folder: str) -> bool:
    cache = os.path.join(folder, "__pycache__")
    return os.access(cache if os.path.isdir(cache) else folder, os.W_OK)


def _seeded(cache: str, seed: str | None) -> None:
    """``cache`` made a copy of the folder ``seed`` unless it exists (or ``seed`` does not): copied
    beside it, then renamed into place, so that processes starting together see all of it or none."""
    if not seed or not os.path.isdir(seed) or os.path.exists(cache):
        return
    part = f"{cache}.part-{os.getpid()}"
    try:
        shutil.copytree(seed, part)
        os.rename(part, cache)
    except OSError:                       # another process was first, or no room: numba compiles
        shutil.rmtree(part, ignore_errors=True)


if not config.CACHE_DIR and not _writable(os.path.dirname(os.path.abspath(__file__))):
    config.CACHE_DIR = os.path.join(tempfile.gettempdir(), f"aocnn-numba-{os.getuid()}")
    _seeded(config.CACHE_DIR, os.environ.get("AOCNN_NUMBA_SEED"))

compiled = numba.njit(cache=True, nogil=True)
"""The decorator of every kernel of the package."""
inlined = numba.njit(cache=True, nogil=True, inline="always")
"""The decorator of a kernel's small helper: its body is inlined into the kernels that call it
(numba's own inlining: no call, no tuple passed through memory, per node of a walk)."""
