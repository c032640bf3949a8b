"""Dynamic batching, as Triton's dynamic batcher does: requests for one model that arrive within a
short window (or while the model is busy) run as one batch.

Invariant: every submitted request's future is resolved exactly once (its result, its own 4xx,
or the batch's error); a batch is at most ``max_batch`` requests; with ``window_s`` 0 each
request is its own batch.
"""

from __future__ import annotations

import asyncio
from typing import Callable

from .errors import ServiceError
from .limiter import Limiter


class Batcher:
    """Collects requests for ``run`` (a blocking function from a list of requests to a list of
    results or ServiceErrors) and runs them through the limiter in batches."""

    def __init__(self, run: Callable[[list], list], limiter: Limiter, window_s: float, max_batch: int,
                 timeout: float):
        self.run, self.limiter = run, limiter
        self.window_s, self.max_batch, self.timeout = window_s, max_batch, timeout
        self.pending: list[tuple[object, asyncio.Future]] = []
        self.timer: asyncio.TimerHandle | None = None
        self.running: set[asyncio.Task] = set()

    async def submit(self, request):
        loop = asyncio.get_running_loop()
        future = loop.create_future()
        self.pending.append((request, future))
        if self.window_s <= 0 or len(self.pending) >= self.max_batch:
            self._flush()
        elif self.timer is None:
            self.timer = loop.call_later(self.window_s, self._flush)
        try:
            return await asyncio.wait_for(asyncio.shield(future), self.timeout)
        except (asyncio.TimeoutError, TimeoutError):
            raise ServiceError("timeout", f"the request did not finish within {self.timeout:g} s",
                           "send a smaller input or raise AOCNN_TIMEOUT_S") from None

    def _flush(self) -> None:
        if self.timer is not None:
            self.timer.cancel()
            self.timer = None
        batch, self.pending = self.pending, []
        if batch:
            task = asyncio.ensure_future(self._run(batch))
            self.running.add(task)
            task.add_done_callback(self.running.discard)

    async def _run(self, batch: list) -> None:
        requests = [r for r, _ in batch]
        self.limiter.metrics.batch.observe(len(requests))
        try:
            results = await self.limiter.run(lambda: self.run(requests), self.timeout)
        except Exception as exc:                # busy (503), timeout (504), or a bug (500): every request
            results = [exc] * len(batch)
        for (_, future), result in zip(batch, results):
            if future.done():
                continue
            if isinstance(result, BaseException):
                future.set_exception(result)
            else:
                future.set_result(result)
