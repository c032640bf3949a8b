"""Crash-safe file writes: data goes to a temporary file beside the target, then is renamed."""

from __future__ import annotations

import os
import tempfile
from contextlib import contextmanager
from pathlib import Path
from typing import Iterator

TEMP_PREFIX = "tmp-"
"""Temporary names start with this (no leading dot: torch's zip writer rejects those)."""


@contextmanager
def atomic_path(path: str | Path, fsync: bool = False) -> Iterator[str]:
    """A temporary path beside ``path`` (same suffix) that replaces ``path`` when the block ends
    without error, and is removed otherwise: readers see the old file or the whole new one."""
    path = Path(path)
    fd, tmp = tempfile.mkstemp(prefix=TEMP_PREFIX, suffix=path.suffix, dir=path.parent)
    os.close(fd)
    try:
        yield tmp
        if fsync:
            with open(tmp, "rb") as fh:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_atomic(path: str | Path, data: bytes, fsync: bool = False) -> None:
    """Write ``data`` to ``path`` through :func:`atomic_path`."""
    with atomic_path(path, fsync) as tmp:
        with open(tmp, "wb") as fh:
            fh.write(data)
