"""The compiled kernels' work shared between cores: they release the GIL, so threads run them in
parallel.  One pool for the process (a pool started per call costs about a millisecond)."""

from __future__ import annotations

import os
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor

import numpy as np

WORKERS = max(1, min(os.cpu_count() or 1, 4))
"""Threads of the pool, and parts a large job is split into."""
_POOL = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="octree-kernel")


def split(n: int, parts: int) -> list[int]:
    """``parts + 1`` ascending bounds splitting ``range(n)`` into near-equal contiguous parts."""
    return np.linspace(0, n, max(1, parts) + 1).astype(np.int64).tolist()


def run_parts(work: Callable[[int, int], None], n: int, parts: int = WORKERS) -> None:
    """``work(a, b)`` over contiguous parts of ``range(n)``: in the pool when there are several,
    here when there is one; every part is done when it returns (their errors are raised)."""
    bounds = split(n, min(parts, n) if n else 1)
    if len(bounds) <= 2:
        work(bounds[0], bounds[-1])
        return
    futures = [_POOL.submit(work, a, b) for a, b in zip(bounds[:-1], bounds[1:])]
    for f in futures:
        f.result()
