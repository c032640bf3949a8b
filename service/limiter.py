"""The bounded executor every CPU-bound request runs in.

Invariant: at most ``concurrency`` inferences run at once, each with ``threads`` onnxruntime
threads, and ``concurrency * threads`` never exceeds the CPUs the process may use; at most
``queue`` requests wait for a slot, the next ones get 503 with Retry-After.  A slot is released
when its work has really finished (a timed-out request's thread still holds it until then).
"""

from __future__ import annotations

import asyncio
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Callable

from export.runtime import available_cpus

from .errors import ServiceError
from .metrics import Metrics
from .settings import Settings


def plan_threads(settings: Settings, cpus: int | None = None) -> tuple[int, int]:
    """(concurrency, threads per inference) with concurrency * threads <= the CPUs available."""
    cpus = cpus or available_cpus()
    concurrency = min(settings.concurrency or max(1, cpus // 2), cpus)
    threads = settings.threads or max(1, cpus // concurrency)
    if concurrency * threads > cpus:
        threads = max(1, cpus // concurrency)
    return concurrency, threads


class Limiter:
    """Runs blocking work in a bounded thread pool with a bounded wait (see the module invariant)."""

    def __init__(self, concurrency: int, queue: int, metrics: Metrics):
        self.concurrency, self.queue, self.metrics = concurrency, queue, metrics
        self.executor = ThreadPoolExecutor(max_workers=concurrency, thread_name_prefix="infer")
        self.slots = asyncio.Semaphore(concurrency)
        self.waiting = 0

    async def run(self, fn: Callable, timeout: float):
        if self.slots.locked() and self.waiting >= self.queue:
            raise ServiceError("busy", f"all {self.concurrency} inference slots are busy and {self.waiting} "
                           "requests are waiting", "retry after the number of seconds in Retry-After",
                           {"Retry-After": "1"})
        start = time.perf_counter()
        self.waiting += 1
        self.metrics.waiting.inc()
        try:
            await asyncio.wait_for(self.slots.acquire(), timeout)
        except (asyncio.TimeoutError, TimeoutError):
            raise ServiceError("timeout", f"no inference slot became free within {timeout:g} s",
                           "retry later or raise AOCNN_TIMEOUT_S", {"Retry-After": "1"}) from None
        finally:
            self.waiting -= 1
            self.metrics.waiting.dec()
        waited = time.perf_counter() - start
        self.metrics.queue.observe(waited)

        def work():
            self.metrics.in_flight.inc()
            try:
                return fn()
            finally:
                self.metrics.in_flight.dec()

        future = asyncio.get_running_loop().run_in_executor(self.executor, work)
        future.add_done_callback(lambda _: self.slots.release())
        try:
            return await asyncio.wait_for(asyncio.shield(future), max(timeout - waited, 0.001))
        except (asyncio.TimeoutError, TimeoutError):
            raise ServiceError("timeout", f"the request did not finish within {timeout:g} s",
                           "send a smaller input or raise AOCNN_TIMEOUT_S") from None

    def close(self) -> None:
        self.executor.shutdown(wait=False, cancel_futures=True)
