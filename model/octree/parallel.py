"""The compiled kernels' work shared between cores: they release the GIL, so threads run them in
parallel.  One pool per process (a pool started per call costs about a millisecond), made
afresh in a forked child, whose copy of the parent's pool has no threads behind it; and a pool
of its own for work run beside a serial step (:func:`beside`)."""

from __future__ import annotations

import os
import threading
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TypeVar

import numpy as np

WORKERS = max(1, min(os.cpu_count() or 1, 4))
"""Threads of the pool, and parts a large job is split into."""
SPARE_WORKERS = max(WORKERS, os.cpu_count() or 1)
"""Threads of the pool of work beside (:func:`beside`): one per CPU, so that the service's
inference threads (at most one per CPU) never queue their work beside behind one another."""
_pool: ThreadPoolExecutor | None = None
_spare: ThreadPoolExecutor | None = None
_making = threading.Lock()
T = TypeVar("T")


def _forget_pool() -> None:
    global _pool, _spare, _making
    _pool = _spare = None
    _making = threading.Lock()                # a lock held in the parent at the fork stays held in the child


os.register_at_fork(after_in_child=_forget_pool)


def _the_pool() -> ThreadPoolExecutor:
    global _pool
    with _making:
        if _pool is None:
            _pool = ThreadPoolExecutor(max_workers=WORKERS, thread_name_prefix="octree-kernel")
        return _pool


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
    futures = [_the_pool().submit(work, a, b) for a, b in zip(bounds[:-1], bounds[1:])]
    for f in futures:
        f.result()


def beside(work: Callable[[], T]) -> Future[T]:
    """``work()`` started on the spare core while the caller goes on with serial work, in a thread
    of a pool of its own (so that ``work`` may share its own work through :func:`run_parts`
    without waiting on the thread it runs in; :data:`SPARE_WORKERS` threads, so that callers in
    several threads do not queue behind one another); run here, and done, on a one-core machine.
    The caller waits on the future (its error is raised there); ``work`` must not itself wait on
    work beside."""
    global _spare
    if WORKERS < 2:
        done: Future[T] = Future()
        try:
            done.set_result(work())
        except Exception as exc:              # raised where the caller waits, as from a thread
            done.set_exception(exc)
        return done
    with _making:
        if _spare is None:
            _spare = ThreadPoolExecutor(max_workers=SPARE_WORKERS, thread_name_prefix="octree-beside")
        return _spare.submit(work)
