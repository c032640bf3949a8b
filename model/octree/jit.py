"""How the octree's kernels are compiled: numba, machine code cached on disk, the GIL released.

numba keeps the machine code beside the sources (``__pycache__``) or in the user's cache; an
install that can write neither (a Docker image run as an unprivileged user with no home, a
read-only site-packages) would fail at import.  Such an install caches in a per-user folder of the
system's temporary directory instead, unless ``NUMBA_CACHE_DIR`` says where.
"""

from __future__ import annotations

import os
import tempfile

import numba
from numba.core import config


def _writable(folder: str) -> bool:
    cache = os.path.join(folder, "__pycache__")
    return os.access(cache if os.path.isdir(cache) else folder, os.W_OK)


if not config.CACHE_DIR and not _writable(os.path.dirname(os.path.abspath(__file__))):
    config.CACHE_DIR = os.path.join(tempfile.gettempdir(), f"aocnn-numba-{os.getuid()}")

compiled = numba.njit(cache=True, nogil=True)
"""The decorator of every kernel of the package."""
