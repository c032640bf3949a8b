"""A bundle's graphs in onnxruntime: encoders, the decoder steps of :mod:`model.decode`, threads.

No torch here (the service imports this).  Sessions are created once per :class:`Runtime`, with
the thread count taken from the CPUs this process may really use (affinity and cgroup quota,
not the host's core count), and their inputs and outputs checked against the bundle's spec.
The decode loop is :func:`model.decode.decode`; :class:`OrtSteps` only runs its steps.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np
import onnxruntime as ort

from model.decode import Guide, decode
from model.image.mask import mask_input, mask_output
from model.octree import Octree

from .bundle import Bundle, BundleError, GraphSpec

ORT_DTYPES = {"tensor(float)": "float32", "tensor(int64)": "int64"}


def _cgroup_cpus(root: Path = Path("/sys/fs/cgroup")) -> float | None:
    """CPUs allowed by the cgroup CPU quota (v2 cpu.max or v1 cfs quota), None if unlimited."""
    try:
        quota, period = (root / "cpu.max").read_text().split()[:2]
        if quota != "max":
            return int(quota) / int(period)
        return None
    except (OSError, ValueError):
        pass
    try:
        quota = int((root / "cpu" / "cpu.cfs_quota_us").read_text())
        period = int((root / "cpu" / "cpu.cfs_period_us").read_text())
        return quota / period if quota > 0 and period > 0 else None
    except (OSError, ValueError):
        return None


def available_cpus(cgroup_root: Path = Path("/sys/fs/cgroup")) -> int:
    """CPUs this process may use: its affinity mask, capped by the cgroup quota (rounded up)."""
    try:
        cpus = len(os.sched_getaffinity(0))
    except AttributeError:                      # not Linux
        cpus = os.cpu_count() or 1
    quota = _cgroup_cpus(cgroup_root)
    if quota is not None:
        cpus = min(cpus, max(1, math.ceil(quota)))
    return max(1, cpus)


def session_options(threads: int, spinning: bool = True) -> ort.SessionOptions:
    """One session's options: ``threads`` intra-op threads, full graph optimisation, no memory
    pattern planning (node counts change on every call, so plans would not be reused).
    ``spinning`` False stops idle intra-op threads from busy-waiting for work (a server whose
    other threads parse requests and build octrees wants the CPU back)."""
    so = ort.SessionOptions()
    if not spinning:
        so.add_session_config_entry("session.intra_op.allow_spinning", "0")
    so.intra_op_num_threads = threads
    so.inter_op_num_threads = 1
    so.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    so.graph_optimization_level = ort.GraphOptimizationLevel.ORT_ENABLE_ALL
    so.enable_mem_pattern = False
    so.log_severity_level = 3
    return so


def _check_io(spec: GraphSpec, session: ort.InferenceSession, path: Path) -> None:
    """The session's inputs and outputs must be those of the spec (names, dtypes, static sizes)."""
    for kind, args, want in (("input", session.get_inputs(), spec.inputs),
                             ("output", session.get_outputs(), spec.outputs)):
        got = {a.name: a for a in args}
        if set(got) != set(want):
            raise BundleError(f"{path}: graph {kind}s {sorted(got)} do not match model.json {sorted(want)}")
        for name, (dtype, shape) in want.items():
            a = got[name]
            if ORT_DTYPES.get(a.type) != dtype or len(a.shape) != len(shape) or any(
                    isinstance(s, int) and isinstance(g, int) and s != g for s, g in zip(shape, a.shape)):
                raise BundleError(f"{path}: {kind} {name!r} is {a.type} {a.shape}, model.json says {dtype} {list(shape)}")


class Runtime:
    """The onnxruntime sessions of one verified bundle (thread-safe: sessions may run concurrently)."""

    def __init__(self, bundle: Bundle, threads: int | None = None, spinning: bool = True):
        self.bundle, self.threads = bundle, threads or available_cpus()
        options = session_options(self.threads, spinning)
        self.sessions: dict[str, ort.InferenceSession] = {}
        for name, spec in bundle.graphs.items():
            path = bundle.file(name)
            try:
                session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
            except Exception as exc:                    # onnxruntime raises its own exception types
                raise BundleError(f"{path}: onnxruntime cannot load it ({str(exc).splitlines()[0]})") from None
            _check_io(spec, session, path)
            self.sessions[name] = session

    def run(self, graph: str, feeds: dict[str, np.ndarray]) -> list[np.ndarray]:
        return self.sessions[graph].run(None, feeds)

    def encode_image(self, images: np.ndarray) -> np.ndarray:
        """Latent codes (B, L) of preprocessed images (B, 3, S, S) (:func:`model.image.frame.prepare_image`)."""
        return self.run("image_encoder", {"image": np.ascontiguousarray(images, dtype=np.float32)})[0]

    def segment(self, rgb: np.ndarray) -> np.ndarray:
        """(size, size) object probability, on the network's grid over the whole image, of an
        (H, W, 3|4) uint8 image (its colour channels, read as they lie) by the bundle's foreground
        network (:func:`model.image.mask.mask_input` / :func:`mask_output`;
        :func:`model.image.mask.to_image` brings it to the image); ValueError without one."""
        spec = self.bundle.mask_spec()
        if spec is None:
            raise ValueError(f"{self.bundle.path}: the bundle has no foreground network")
        logits = self.run("foreground", {"image": mask_input(rgb, spec)[None]})[0]
        return mask_output(logits[0, 0])

    def refine(self, x: np.ndarray) -> np.ndarray:
        """(S, S) object probability of a refinement input (4, S, S) (:func:`model.image.mask.crop_input`)
        by the bundle's refinement network; ValueError without one."""
        if "foreground_refine" not in self.sessions:
            raise ValueError(f"{self.bundle.path}: the bundle has no refinement network")
        logits = self.run("foreground_refine", {"image": np.ascontiguousarray(x[None], dtype=np.float32)})[0]
        return mask_output(logits[0, 0])

    @property
    def has_refine(self) -> bool:
        return "foreground_refine" in self.sessions

    @property
    def has_foreground(self) -> bool:
        return self.bundle.mask_spec() is not None

    def encode_octree(self, octree: Octree) -> np.ndarray:
        """Latent codes (B, L) of a (batched) octree built with the bundle's octree settings."""
        return self.encode_scan(octree)[0]

    def encode_scan(self, octree: Octree) -> tuple[np.ndarray, Guide | None]:
        """Latent codes (B, L) of a (batched) octree and, for a guided bundle, the :class:`Guide`
        its decoder reads (the encoder's features of every depth's octants)."""
        out = self.run("octree_encoder", octree_feeds(octree, self.bundle.graphs["octree_encoder"]))
        if not self.bundle.octree.guided:
            return out[0], None
        names = [o.name for o in self.sessions["octree_encoder"].get_outputs()]
        return out[0], Guide.of(octree, {int(n.rsplit("_", 1)[1]): x for n, x in zip(names, out) if n.startswith("skip_")})

    def classify(self, latent: np.ndarray) -> np.ndarray:
        """Class probabilities (B, C) of latent codes (B, L) (a classify bundle's head)."""
        return self.run("classifier_head", {"latent": np.ascontiguousarray(latent, dtype=np.float32)})[0]

    def steps(self, depth: int | None = None) -> OrtSteps:
        return OrtSteps(self, depth)

    def decode(self, latent: np.ndarray, depth: int | None = None,
               empty_bias: dict[int, float] | None = None, guide: Guide | None = None) -> Octree:
        """Grow the octrees of latent codes (B, L) down to ``depth`` (default: the bundle's);
        ``empty_bias`` and ``guide`` (a guided bundle's: :meth:`encode_scan`) as
        :func:`model.decode.decode`'s."""
        o = self.bundle.octree
        if o.guided and guide is None:
            raise ValueError("a guided bundle decodes with the guide of its input (encode_scan)")
        return decode(self.steps(depth), np.asarray(latent, np.float32), o.full_depth, o.adaptive_depth, empty_bias,
                      guide)


def octree_feeds(octree: Octree, spec: GraphSpec) -> dict[str, np.ndarray]:
    """The octree encoder's inputs: per depth the plane signal, neighbour table and split nodes."""
    if not octree.has_neighbors:
        raise ValueError("the octree needs neighbour tables (build_octree(..., neighbors=True))")
    feeds = {}
    for name in spec.inputs:
        kind, d = name.rsplit("_", 1)
        lv = octree.levels[int(d)]
        feeds[name] = (np.ascontiguousarray(lv.plane, dtype=np.float32) if kind == "signal"
                       else lv.neighbors.astype(np.int64) if kind == "neighbors"
                       else lv.split_nodes().astype(np.int64))
    return feeds


class OrtSteps:
    """:class:`model.decode.DecoderSteps` over a :class:`Runtime`'s decoder graphs (NumPy features).

    ``depth`` below the bundle's stops the growth there (a coarser level of detail).
    """

    def __init__(self, runtime: Runtime, depth: int | None = None):
        spec = runtime.bundle.octree
        depth = spec.depth if depth is None else depth
        if not spec.full_depth <= depth <= spec.depth:
            raise ValueError(f"depth must be in {spec.full_depth}..{spec.depth}, got {depth}")
        self.runtime, self.spec, self.depth = runtime, spec, depth

    def classes(self, depth: int) -> int:
        return self.spec.classes[depth]

    def start(self, latent: np.ndarray) -> np.ndarray:
        return self.runtime.run("decoder_start", {"latent": np.ascontiguousarray(latent, dtype=np.float32)})[0]

    def predict(self, depth: int, features: np.ndarray, neighbors: np.ndarray, skip: np.ndarray | None = None,
                skip_index: np.ndarray | None = None):
        feeds = {"features": features, "neighbors": neighbors.astype(np.int64)}
        if skip is not None:
            feeds.update(skip=skip, skip_index=skip_index.astype(np.int64))
        out = self.runtime.run(f"decoder_predict_{depth}", feeds)
        return out[0], out[1], out[2] if len(out) > 2 else None

    def expand(self, depth: int, features: np.ndarray, split: np.ndarray) -> np.ndarray:
        return self.runtime.run(f"decoder_expand_{depth}", {"features": features, "split": split.astype(np.int64)})[0]
