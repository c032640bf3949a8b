"""Prometheus metrics of one app (its own registry, so several apps may live in one process)."""

from __future__ import annotations

import time
from contextlib import contextmanager

from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

STAGES = ("decode_input", "mask", "octree_build", "encoder", "decoder", "keep_scan", "surface", "mesh_encode")
LATENCY_BUCKETS = (0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30, 60)


class Metrics:
    """Requests by endpoint and status, latency, time per stage, queue time, in-flight inferences."""

    def __init__(self):
        self.registry = CollectorRegistry()
        r = self.registry
        self.requests = Counter("aocnn_requests", "HTTP requests by endpoint and status", ["endpoint", "status"], registry=r)
        self.latency = Histogram("aocnn_request_seconds", "request latency", ["endpoint"], buckets=LATENCY_BUCKETS, registry=r)
        self.stage = Histogram("aocnn_stage_seconds", "time per inference stage", ["stage"], buckets=LATENCY_BUCKETS, registry=r)
        self.queue = Histogram("aocnn_queue_seconds", "time waiting for an inference slot", buckets=LATENCY_BUCKETS, registry=r)
        self.batch = Histogram("aocnn_batch_size", "requests per dynamic batch", buckets=(1, 2, 4, 8, 16, 32, 64),
                               registry=r)
        self.in_flight = Gauge("aocnn_inferences_in_flight", "inferences running now", registry=r)
        self.waiting = Gauge("aocnn_inferences_waiting", "requests waiting for an inference slot", registry=r)


class StageTimer:
    """Seconds per stage of one request (reported to metrics and in the Server-Timing header).

    Stages are disjoint: a stage timed inside another (the foreground network's ``mask`` inside
    ``decode_input``) is not counted in the outer one."""

    def __init__(self, metrics: Metrics):
        self.metrics, self.seconds = metrics, {}
        self.inner: list[float] = []            # per open stage, the seconds of the stages inside it

    @contextmanager
    def __call__(self, stage: str):
        t = time.perf_counter()
        self.seconds.setdefault(stage, 0.0)     # the header lists stages in the order they start
        self.inner.append(0.0)
        try:
            yield
        finally:
            total = time.perf_counter() - t
            nested = self.inner.pop()
            if self.inner:
                self.inner[-1] += total
            self.add(stage, total - nested)

    def add(self, stage: str, seconds: float) -> None:
        self.seconds[stage] = self.seconds.get(stage, 0.0) + seconds
        self.metrics.stage.labels(stage).observe(seconds)

    def header(self) -> str:
        return ", ".join(f"{k};dur={1e3 * v:.1f}" for k, v in self.seconds.items())
