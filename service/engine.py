"""The served models: bundles loaded and verified at startup, warmed up, and the blocking work of
each endpoint, run through the bounded executor (:mod:`service.limiter`) and, for the decoding
tasks, the dynamic batchers (:mod:`service.batching`)."""

from __future__ import annotations

import io
import logging
import time
from dataclasses import dataclass, replace

import numpy as np
from PIL import Image

from export.bundle import Bundle, BundleError, Task, load_bundle
from export.runtime import Runtime
from model.decode import DECODED_NORMALIZATION
from model.image.frame import Framed, compile_framing, frame_object, upload_mask
from model.image.mask import MaskSpec, NoObjectError, object_mask
from model.octree import Octree, PointCloud, build_octree, scan_octree
from model.octree.batch import merge_octrees, split_octree
from model.octree.fuse import keep_scan
from model.octree.geometry import to_y_up, up_rotations
from model.octree.pointcloud import MIN_SCAN_POINTS, estimate_normals
from model.octree.scan import ScanLayout, lay_out_scan
from model.octree.symmetry import Mirror, find_mirror, symmetrize
from model.surface import SURFACES, surface_mesh

from .batching import Batcher
from .errors import ServiceError
from .inputs import image_input, shape_input
from .jobs import ImageJob, ImageResult, MeshOptions, ScanJob, ScanResult
from .limiter import Limiter, plan_threads
from .meshes import MeshFile, encode, encode_mesh
from .metrics import Metrics, StageTimer
from .settings import Settings

log = logging.getLogger("service")


class StartupError(RuntimeError):
    """The service cannot start: the message names the bundle and the problem."""


@dataclass
class Served:
    """One loaded bundle and its onnxruntime sessions."""

    bundle: Bundle
    runtime: Runtime


class Engine:
    """Bundles by task, the limiter and metrics; built once in the app's lifespan."""

    def __init__(self, settings: Settings):
        self.settings = settings
        self.metrics = Metrics()
        self.concurrency, self.threads = plan_threads(settings)
        self.models: dict[str, Served] = {}
        self.limiter: Limiter | None = None
        self.ready = False

    def load(self) -> None:
        """Load and verify every bundle under ``models_dir``; StartupError on the first bad one."""
        root = self.settings.models_dir
        if not root.is_dir():
            raise StartupError(f"{root}: the models folder does not exist (set AOCNN_MODELS_DIR)")
        folders = sorted(p for p in root.iterdir() if p.is_dir() and not p.name.startswith(("tmp-", ".")))
        if not folders:
            raise StartupError(f"{root}: holds no bundle folders (export one with python -m export)")
        for folder in folders:
            try:
                bundle = load_bundle(folder)
                served = Served(bundle, Runtime(bundle, threads=self.threads, spinning=self.settings.spinning))
            except BundleError as exc:
                raise StartupError(f"bundle {folder.name}: {exc}") from None
            if bundle.task in self.models:
                raise StartupError(f"bundles {self.models[bundle.task].bundle.path.name} and {folder.name} both "
                                   f"serve {bundle.task}; keep one")
            self.models[bundle.task] = served
        self.limiter = Limiter(self.concurrency, self.settings.queue, self.metrics)
        st = self.settings
        self.batchers = {task: Batcher(fn, self.limiter, st.batch_window_ms / 1e3, st.max_batch, st.timeout_s)
                         for task, fn in ((Task.IMAGE_TO_SHAPE, self.image_batch), (Task.COMPLETION, self.complete_batch))}

    def warm_up(self) -> None:
        """One inference per model (first calls allocate and optimise), one normal estimation and
        one symmetry search (their kernels compile on their first call: seconds, where no cache
        was written; the octree build's, the scan fusion's, the photo mask's and an opaque photo's
        framing compile with the models' warm-up, which also runs the foreground network once);
        then the service is ready."""
        points = _sphere(200)[0]
        estimate_normals(points)
        find_mirror(points)
        for served in self.models.values():
            rt, b = served.runtime, served.bundle
            guide = None
            if b.task == Task.IMAGE_TO_SHAPE:
                size = b.image_spec().size
                latent = rt.encode_image(np.zeros((1, 3, size, size), np.float32))
                frame_object(np.full((48, 64, 4), 255, np.uint8), b.image_spec(), remove_background="false")
                if rt.has_foreground:                      # its network, and the framing's kernels
                    try:
                        object_mask(np.zeros((240, 320, 4), np.uint8), rt.segment, b.mask_spec())
                    except NoObjectError:
                        pass
                    compile_framing(b.image_spec(), b.mask_spec())
            elif b.task in (Task.COMPLETION, Task.AUTOENCODER, Task.CLASSIFY):
                scan = build_octree(_sphere(), b.octree.depth, adaptive=b.octree.adaptive)
                latent, guide = rt.encode_scan(scan)
                if b.task == Task.CLASSIFY:
                    rt.classify(latent)
                    continue
            else:
                continue
            octree = rt.decode(latent, guide=guide)
            if b.task == Task.COMPLETION:                    # the fusion with the scan's patches
                decoded = split_octree(octree, neighbors=False)[0]
                decoded.normalizations = list(scan.normalizations)
                keep_scan(decoded, scan)
            if any(octree.leaves_per_depth()):               # first exports import and compile lazily
                for fmt in ("glb", "gltf", "ply", "obj"):
                    for surface in SURFACES:
                        encode_mesh(octree, fmt, surface=surface)
        self.ready = True

    def model(self, task: str) -> Served:
        if task not in self.models:
            raise ServiceError("no_model", f"no {task} model is installed in this service",
                           f"add a {task} bundle to AOCNN_MODELS_DIR and restart; GET /v1/models lists what is served",
                           {"Retry-After": "3600"})
        return self.models[task]

    def check_depth(self, served: Served, depth: int | None) -> int:
        o = served.bundle.octree
        if depth is None:
            return o.depth
        if not o.adaptive_depth <= depth <= o.depth:
            raise ServiceError("invalid_depth", f"depth must be in {o.adaptive_depth}..{o.depth} for this model, "
                           f"got {depth}", "omit depth for the model's full detail")
        return depth

    # -- the blocking work of each endpoint (runs in the limiter's threads) -----------------
    def frame_image(self, job: ImageJob) -> Framed:
        """A photo decoded, its object found (alpha, or the foreground network timed as the ``mask``
        stage) and framed for the encoder."""
        served = self.model(Task.IMAGE_TO_SHAPE)
        b = served.bundle

        def segment(rgb: np.ndarray) -> np.ndarray:
            with job.timer("mask"):
                return served.runtime.segment(rgb)

        def refine(x: np.ndarray) -> np.ndarray:
            with job.timer("mask"):
                return served.runtime.refine(x)

        with job.timer("decode_input"):
            return image_input(job.data, b.image_spec(), self.settings.max_image_pixels,
                               segment if served.runtime.has_foreground else None, job.remove_background,
                               job.foreground_ratio, b.mask_spec() or MaskSpec(),
                               refine if served.runtime.has_refine else None, job.box)

    def mask_png(self, job: ImageJob) -> tuple[bytes, Framed]:
        """The mask a photo's framing used, as an 8-bit greyscale PNG of the photo's size (debug=mask),
        and the framing; ``no_mask`` for an opaque photo framed without one."""
        framed = self.frame_image(job)
        if framed.mask is None:
            if job.remove_background == "false":
                raise ServiceError("no_mask", "there is no mask: the image is opaque and remove_background=false "
                                   "keeps its background", "drop remove_background=false to see the foreground "
                                   "network's mask, or send a PNG with transparency around the object")
            raise ServiceError("no_mask", "there is no mask: the image is opaque and this model has no foreground "
                               "network to find the object", "send a PNG with transparency around the object")
        buf = io.BytesIO()
        Image.fromarray(upload_mask(framed)).save(buf, format="PNG")
        return buf.getvalue(), framed

    def image_batch(self, jobs: list[ImageJob]) -> list[ImageResult | ServiceError]:
        """Photos -> meshes, encoded and decoded as one batch; a bad input fails only its own job."""
        served = self.model(Task.IMAGE_TO_SHAPE)

        def prepare(job: ImageJob) -> tuple[np.ndarray, Framed]:
            framed = self.frame_image(job)
            return framed.image, framed

        def encode(inputs):
            return served.runtime.encode_image(np.stack(inputs)), None

        def finish(tree: Octree, framed: Framed, job: ImageJob) -> ImageResult:
            tree.normalizations = [DECODED_NORMALIZATION]
            return ImageResult(_mesh(tree, job.mesh, job.timer), framed)

        return self._batch(served, jobs, prepare, encode, finish)

    def complete_batch(self, jobs: list[ScanJob]) -> list[ScanResult | ServiceError]:
        """Partial scans -> completed meshes in each scan's frame, as one batch."""
        served = self.model(Task.COMPLETION)
        o = served.bundle.octree

        def prepare(job: ScanJob) -> tuple[Octree, tuple[Octree, Mirror | None, int]]:
            layout = _Layout(job.up, o.depth, o.adaptive, job.symmetry)
            with job.timer("decode_input"):       # the layout is found beside the normals' orientation
                loaded = shape_input(job.data, job.filename, o.depth, self.settings.max_points,
                                     self.settings.max_npz_bytes, beside=layout)
            strays = loaded.cloud.strays
            if len(loaded.cloud) < MIN_SCAN_POINTS:
                dropped = f" once {strays} far from the rest are dropped" if strays else ""
                raise ServiceError("too_few_points", f"the scan has {len(loaded.cloud)} points{dropped}; completion "
                                   f"needs at least {MIN_SCAN_POINTS}", "send the scanner's whole point cloud")
            mirror = None
            with job.timer("octree_build"):       # the scan's frame, as the model was trained
                cloud = _upright(loaded.cloud, job.up)      # as the network was trained
                if job.symmetry:
                    cloud, mirror = symmetrize(cloud, mirror=layout.found.mirror)
                scan = scan_octree(cloud, o.depth, adaptive=o.adaptive, full_depth=o.full_depth,
                                   adaptive_depth=o.adaptive_depth, placement=layout.found.placement,
                                   **({"threshold": o.threshold} if o.threshold else {}))
            return scan, (scan, mirror, strays)

        def encode(trees):
            return served.runtime.encode_scan(merge_octrees(trees))

        def finish(tree: Octree, found: tuple[Octree, Mirror | None, int], job: ScanJob) -> ScanResult:
            scan, mirror, strays = found
            tree.normalizations = list(scan.normalizations)   # decoded in the scan's frame
            if job.keep_scan:
                with job.timer("keep_scan"):
                    tree = keep_scan(tree, scan)
            back = None if job.up == "y" else to_y_up(job.up).T     # to the upload's up axis
            return ScanResult(_mesh(tree, job.mesh, job.timer, back), mirror, strays)

        return self._batch(served, jobs, prepare, encode, finish)

    def _batch(self, served: Served, jobs: list, prepare, encode, finish) -> list:
        """Prepare each job (``prepare(job)`` -> the encoder's input and what ``finish`` needs; a
        job's own errors kept for it), encode all (``encode`` -> latent codes and a guided decoder's
        :class:`~model.decode.Guide` or None), decode per depth (and keep_scan: its outputs decode
        with the bundle's keep_scan bias), and ``finish(tree, found, job)`` each decoded tree into
        the job's result."""
        out: list = [None] * len(jobs)
        ready, depths = [], {}
        for i, job in enumerate(jobs):
            try:
                depths[i] = self.check_depth(served, job.mesh.depth)
                ready.append((i, *prepare(job)))
            except ServiceError as exc:
                out[i] = exc
        if not ready:
            return out
        t = time.perf_counter()
        latent, guide = encode([x for _, x, _ in ready])        # guide: a guided decoder's input
        _share([jobs[i] for i, _, _ in ready], "encoder", time.perf_counter() - t)
        bias = served.bundle.keep_scan_bias        # the decode setting of outputs that keep the scan
        keeps = {i: getattr(jobs[i], "keep_scan", False) for i, _, _ in ready}
        for depth, keep in sorted({(depths[i], keeps[i]) for i, _, _ in ready}):
            group = [k for k, (i, _, _) in enumerate(ready) if (depths[i], keeps[i]) == (depth, keep)]
            t = time.perf_counter()
            decoded = split_octree(served.runtime.decode(latent[group], depth, bias if keep else None,
                                                         guide and guide.subset(np.array(group))),
                                   neighbors=False)
            _share([jobs[ready[k][0]] for k in group], "decoder", time.perf_counter() - t)
            for k, tree in zip(group, decoded):
                i, _, found = ready[k]
                try:
                    out[i] = finish(tree, found, jobs[i])
                except ServiceError as exc:
                    out[i] = exc
        return out

    def classify(self, data: bytes, filename: str | None, vote: bool, timer: StageTimer,
                 up: str = "y") -> tuple[np.ndarray, int]:
        """Class probabilities (R, C) of a shape at R rotations about the bundle's up axis: 12 with
        ``vote`` (the paper's test-time vote, 12x the work), else 1; the shape first turned from its
        up axis ``up`` to the model's; and how many of its points far from the rest were dropped."""
        served = self.model(Task.CLASSIFY)
        b = served.bundle
        o = b.octree
        with timer("decode_input"):
            loaded = shape_input(data, filename, o.depth, self.settings.max_points, self.settings.max_npz_bytes,
                                 "shape")
        model_up = b.input.get("points", {}).get("up", "y")
        rotations = up_rotations(model_up)[:None if vote else 1]
        with timer("octree_build"):            # from the upload's up axis to the model's
            c = _upright(loaded.cloud, up, model_up)
            trees = [build_octree(c.rotated(r), o.depth, adaptive=o.adaptive,
                                  full_depth=o.full_depth, adaptive_depth=o.adaptive_depth,
                                  sample_spacing=loaded.sample_spacing,
                                  **({"threshold": o.threshold} if o.threshold else {}))
                     for r in rotations]
        with timer("encoder"):
            return served.runtime.classify(served.runtime.encode_octree(merge_octrees(trees))), loaded.cloud.strays

    def octree(self, data: bytes, filename: str | None, threshold: float | None, full: bool, options: MeshOptions,
               timer: StageTimer) -> tuple[MeshFile, int]:
        """The mesh of a shape's octree at ``options.depth``, and how many of its points far from the
        rest were dropped."""
        with timer("decode_input"):
            loaded = shape_input(data, filename, options.depth, self.settings.max_points, self.settings.max_npz_bytes,
                                 "shape")
        with timer("octree_build"):
            tree = build_octree(loaded.cloud, options.depth, adaptive=not full, neighbors=False,
                                sample_spacing=loaded.sample_spacing, **({"threshold": threshold} if threshold else {}))
        return _mesh(tree, options, timer), loaded.cloud.strays


def _mesh(octree, options: MeshOptions, timer: StageTimer, rotation: np.ndarray | None = None) -> MeshFile:
    """The mesh file of an octree as ``options`` ask, its vertices turned by ``rotation`` (back to
    the upload's up axis) when given; ``empty_output`` for a decoded octree without leaves."""
    if not any(octree.leaves_per_depth()):
        raise ServiceError("empty_output", "the model decoded no surface from this input",
                           "send a photo or scan of one object, centred, on a plain background")
    with timer("surface"):
        m = surface_mesh(octree, options.surface, faces=options.faces)
        if rotation is not None:
            m = replace(m, vertices=m.vertices @ rotation.T)
    with timer("mesh_encode"):
        return encode(m, octree, options.fmt, options.color)


def _upright(cloud: PointCloud, up: str, model_up: str = "y") -> PointCloud:
    """An upload whose up axis is ``up`` turned to the model's up axis (itself when they agree)."""
    return cloud if up == model_up else cloud.rotated(_up_turn(up, model_up))


def _up_turn(up: str, model_up: str = "y") -> np.ndarray:
    """The rotation from the up axis ``up`` to the model's ``model_up``."""
    return to_y_up(model_up).T @ to_y_up(up)


class _Layout:
    """A scan's layout (:func:`lay_out_scan`: its mirror plane, and its points placed in the scan
    frame) from its points turned upright as :func:`_upright` turns them: the work given to the
    scan's reading to run beside its normals' orientation; ``found`` holds it once the scan is read."""

    def __init__(self, up: str, depth: int, adaptive: bool, symmetry: bool) -> None:
        self.up, self.depth, self.adaptive, self.symmetry = up, depth, adaptive, symmetry
        self.found: ScanLayout | None = None

    def __call__(self, points: np.ndarray) -> None:
        upright = points if self.up == "y" else points @ _up_turn(self.up).T
        self.found = lay_out_scan(upright, self.depth, adaptive=self.adaptive, symmetry=self.symmetry)


def _share(jobs: list, stage: str, seconds: float) -> None:
    """A batch stage's time, charged to each job of the batch (its latency includes all of it)."""
    for job in jobs:
        job.timer.add(stage, seconds)


def _sphere(n: int = 4000) -> tuple[np.ndarray, np.ndarray]:
    """A unit sphere's points and normals (the warm-up input)."""
    rng = np.random.default_rng(0)
    p = rng.normal(size=(n, 3))
    p /= np.linalg.norm(p, axis=1, keepdims=True)
    return p, p
