"""What another CPU's kernels do to onnxruntime's outputs, made on this one: every float32 output
of a graph moved by a relative 1e-5 (kernels of other instruction sets sum in other orders and
fuse multiply-adds differently: about 1e-6), and the outputs of an int8 graph by one quantisation
step (u8s8 kernels with and without VNNI round and saturate differently).

The change is a fixed function of each value (its bits hashed to a sign and a size), so a graph
run twice on the same input gives the same perturbed output, as one machine's kernels do.
``AOCNN_PERTURB_KERNELS=1e-5 python -m pytest tests/export tests/service`` runs tests under it
(see ``tests/conftest.py``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import numpy as np
import pytest

from export.quantize import output_range
from export.runtime import Runtime


def _hashed(x: np.ndarray) -> np.ndarray:
    """A value in [-1, 1) per element, a fixed function of its float32 bits."""
    bits = np.ascontiguousarray(x, np.float32).view(np.uint32).astype(np.uint64)
    mixed = (bits * np.uint64(2654435761) + np.uint64(0x9E3779B9)) & np.uint64(0xFFFFFFFF)
    return ((mixed >> np.uint64(8)).astype(np.float64) / float(1 << 23) - 1.0).astype(np.float32)


def perturb(x: np.ndarray, relative: float) -> np.ndarray:
    """``x`` (float32) with every element moved by up to ``relative`` of its own magnitude."""
    x = np.asarray(x)
    if x.dtype != np.float32:
        return x
    return (x * (np.float32(1) + np.float32(relative) * _hashed(x))).astype(np.float32)


def step_perturb(x: np.ndarray, step: float, steps: int = 1) -> np.ndarray:
    """``x`` (an int8 graph's dequantised output) moved by ``steps`` quantisation steps, up or
    down."""
    return (x + np.float32(steps * step) * np.where(_hashed(x) >= 0, 1, -1)).astype(np.float32)


def _int8_steps(runtime: Runtime) -> dict[str, float]:
    """Graph -> the quantisation step of its output, for the bundle's int8 graphs."""
    quantized = runtime.bundle.meta.get("export", {}).get("quantized") or []
    out = {}
    for name in quantized:
        spec = runtime.bundle.graphs[name]
        out[name] = output_range(runtime.bundle.file(name).read_bytes(), next(iter(spec.outputs)))[0]
    return out


@contextlib.contextmanager
def perturbed_kernels(relative: float = 1e-5, int8_steps: int = 1) -> Iterator[None]:
    """Within: every :class:`export.runtime.Runtime` run gives perturbed outputs (float32 graphs by
    ``relative``, int8 graphs by ``int8_steps`` quantisation steps)."""
    real = Runtime.run
    steps: dict[int, dict[str, float]] = {}

    def run(self, graph, feeds):
        out = real(self, graph, feeds)
        if id(self) not in steps:
            steps[id(self)] = _int8_steps(self)
        step = steps[id(self)].get(graph)
        if step is not None:
            return [step_perturb(o, step, int8_steps) for o in out]
        return [perturb(o, relative) for o in out]

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr(Runtime, "run", run)
        yield
