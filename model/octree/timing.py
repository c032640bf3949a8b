"""Wall time per named stage of a build, for benchmarks (``build_octree(timings=...)``)."""

from __future__ import annotations

import time
from contextlib import contextmanager


class StageTimes:
    """Accumulates wall time per named stage into ``out`` (a dict; None records nothing)."""

    def __init__(self, out: dict | None):
        self.out = out

    @contextmanager
    def __call__(self, name: str):
        t = time.perf_counter()
        yield
        if self.out is not None:
            self.out[name] = self.out.get(name, 0.0) + time.perf_counter() - t
