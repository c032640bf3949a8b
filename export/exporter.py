"""Checkpoint -> bundle: load a trained model, export its graphs, write and self-check the bundle.

Loadeds: a shipped checkpoint folder (``model.pt`` + ``model.json``, as ``model.release``
writes) or a training run folder (``checkpoint.pt``).  The bundle is written to a temporary
folder beside the target and renamed when complete, after onnxruntime has decoded a few latent
codes and matched torch (:func:`self_check`): a half-written or wrong bundle never appears.
"""

from __future__ import annotations

import dataclasses
import hashlib
import importlib.metadata
import json
import shutil
import tempfile
from pathlib import Path

import numpy as np
import onnx
import torch

from model.data.shapes import CATEGORIES
from model.decode import decode
from model.files import UMASK, json_text, sha256_file, write_atomic
from model.networks import ARCHS, CLASSIFIER_ARCHS, OctreeDecoder, TorchSteps
from model.octree import DEFAULT_THRESHOLD, Octree, build_octree, validate
from model.octree.batch import merge_octrees
from model.octree.pointcloud import SCAN_FRAME_MARGIN
from model.preprocess import MaskSpec
from model.checkpoint import Loaded, load_model
from model.train.tasks import TASKS

from . import graphs as G
from .bundle import BUNDLE_FORMAT, MANIFEST, BundleError, GraphSpec, load_bundle
from .quantize import quantize_static_graph
from .runtime import Runtime

BUNDLE_TASKS = {"image": "image-to-shape", "autoencoder": "autoencoder", "completion": "completion",
                "classify": "classify"}
"""Training task -> bundle task."""
POINT_LIMITS = {"min_points": 100, "max_points": 1_000_000}


def load_source(path: str | Path) -> Loaded:
    """A run or checkpoint folder's model (:func:`model.checkpoint.load_model`), if exportable."""
    try:
        src = load_model(path)
    except ValueError as exc:
        raise BundleError(str(exc)) from None
    if src.config.task not in BUNDLE_TASKS:
        raise BundleError(f"{path}: task {src.config.task!r} cannot be exported; exportable: {', '.join(BUNDLE_TASKS)}")
    if src.config.task != "classify" and not isinstance(src.model.decoder, OctreeDecoder):
        raise BundleError(f"{path}: the {src.config.arch} decoder is a research baseline; only octree decoders export")
    if src.meta.get("source_run"):
        results = Path(path).parent / f"{Path(path).name}_test.json"
        if results.is_file():
            src.meta["evaluation"] = {k: v for k, v in json.loads(results.read_text()).items()
                                      if k not in ("per_shape", "run")}
    return src


def _adaptive_input(cfg) -> bool:
    """Whether the model reads (or grows) adaptive octrees rather than full ones."""
    if cfg.task == "classify":
        return CLASSIFIER_ARCHS[cfg.arch][0] == "adaptive"
    return cfg.task == "image" or ARCHS[cfg.arch].octree == "adaptive"


def _octree_spec(src: Loaded) -> dict:
    cfg = src.config
    adaptive = _adaptive_input(cfg)
    spec = {"adaptive": adaptive, "latent": cfg.latent, "threshold": DEFAULT_THRESHOLD if adaptive else None,
            "signal": getattr(getattr(src.model, "encoder", None), "signal", "all")}
    if getattr(src.model, "guided", False):
        spec["guided"] = True
    if cfg.task == "classify":          # no decoder: the encoder's depths only
        enc = src.model.encoder
        return {"depth": enc.depth, "full_depth": enc.full_depth, "adaptive_depth": min(4, enc.depth),
                "classes": {}, "planes": [], **spec}
    dec: OctreeDecoder = src.model.decoder
    return {"depth": dec.depth, "full_depth": dec.full_depth, "adaptive_depth": dec.adaptive_depth,
            "classes": {str(d): dec.classes(d) for d in range(dec.full_depth, dec.depth + 1)},
            "planes": [d for d in range(dec.full_depth, dec.depth + 1) if dec.has_plane(d)], **spec}


def load_foreground(path: str | Path) -> Loaded:
    """A trained foreground network (run or checkpoint folder) to put in an image bundle."""
    try:
        fg = load_model(path)
    except ValueError as exc:
        raise BundleError(str(exc)) from None
    if fg.config.task != "foreground":
        raise BundleError(f"{path}: a {fg.config.task} run, not a foreground network")
    return fg


def _io_spec(src: Loaded, task: str, foreground: Loaded | None = None) -> tuple[dict, dict]:
    if task == "image-to-shape":
        spec = src.config.image_spec()
        inp = {"kind": "image", "image": dataclasses.asdict(spec)}
        if foreground is not None:
            inp["foreground"] = TASKS["foreground"].spec(foreground.config, foreground.meta).to_dict()
    else:
        inp = {"kind": "points", "points": {**POINT_LIMITS, "normals": "estimated when absent"}}
        if task == "completion":
            inp["points"]["frame"] = {"function": "model.octree.scan_frame", "margin": SCAN_FRAME_MARGIN}
        if task == "classify":
            inp["points"]["up"] = src.config.up
    if task == "classify":
        return inp, {"kind": "probabilities", "classes": list(src.config.categories)}
    out = {"kind": "patches", "coordinates": "unit cube [0, 1]^3 (the service maps them to the input's frame)"}
    if task == "completion" and src.meta.get("keep_scan"):
        out["keep_scan"] = src.meta["keep_scan"]          # the decode setting chosen for keep_scan outputs
    return inp, out


def export_graphs(src: Loaded) -> list[G.Graph]:
    """Every graph the bundle's task runs."""
    model, cfg = src.model, src.config
    if cfg.task == "classify":
        return [G.encoder_graph(model.encoder, cfg.latent), G.classifier_head_graph(model.head, cfg.latent)]
    out = G.decoder_graphs(model.decoder, cfg.latent)
    if cfg.task == "image":
        out.insert(0, G.image_encoder_graph(model.encoder, cfg.image_size, cfg.latent))
    else:
        out.insert(0, G.encoder_graph(model.encoder, cfg.latent, guided=model.decoder.guided))
    return out


FOREGROUND_PRECISIONS = ("int8", "float32")
"""How the export stores the foreground network: statically quantised (the default: 2.1x faster
in onnxruntime, the same mask IoU, docs/RESULTS.md) or as trained."""

FOREGROUND_INT8_AGREEMENT = 0.99
"""The share of mask pixels (logit > 0) an int8 foreground graph must agree on with torch, on
photos it was not calibrated with; a float32 graph must agree on 0.999 within 1e-3 in the logits."""


def foreground_photos(size: int, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Calibration and check inputs of a foreground network, (1, 3, size, size) each: the
    generator's training shapes photographed (:func:`model.data.photos.generated_photos`), every
    other photo in each list."""
    from model.data.photos import generated_photos
    from model.preprocess import mask_input

    spec = MaskSpec(size=size)
    inputs = [mask_input(p.rgb, spec)[None] for p in generated_photos(per_category=2, views=2, seed=seed)]
    return inputs[::2], inputs[1::2]


def foreground_check(runtime: Runtime, foreground: Loaded, photos: list[np.ndarray], precision: str) -> dict:
    """onnxruntime's and torch's masks of ``photos`` (network inputs): raise if they disagree
    beyond the ``precision``'s allowance (:data:`FOREGROUND_INT8_AGREEMENT`)."""
    ours = np.concatenate([runtime.run("foreground", {"image": x})[0] for x in photos])
    with torch.no_grad():
        theirs = foreground.model.net(torch.from_numpy(np.concatenate(photos))).numpy()
    diff = float(np.abs(ours - theirs).max())
    agree = float(np.mean((ours > 0) == (theirs > 0)))
    bad = agree < FOREGROUND_INT8_AGREEMENT if precision == "int8" else diff > 1e-3 or agree < 0.999
    if bad:
        raise BundleError(f"onnxruntime ({precision}) and torch foreground logits differ by {diff:.2e} "
                          f"({agree:.4%} of pixels agree)")
    return {"foreground_logit_max_abs_diff": diff, "foreground_pixel_agreement": agree}


def bundle_version(graphs: dict[str, dict], inp: dict, outp: dict) -> str:
    """The package's version and a digest of what a bundle serves: every graph (its sha256) and the
    input and output settings (the preprocessing, the foreground network's mask settings, the decode
    settings), so that anything that changes an answer changes the version."""
    served = {"graphs": {name: g["sha256"] for name, g in sorted(graphs.items())}, "input": inp, "output": outp}
    return f"{importlib.metadata.version('adaptive-ocnn')}+{hashlib.sha256(json_text(served).encode()).hexdigest()[:12]}"


def probe_octrees(depth: int, batch: int = 3, seed: int = 0) -> Octree:
    """``batch`` merged adaptive octrees (with neighbour tables) of random ellipsoids' half
    surfaces, as a scanner sees them: inputs for checking graphs that read octrees."""
    rng = np.random.default_rng(seed)
    trees = []
    for _ in range(batch):
        n = rng.normal(size=(4000, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        n = n[n[:, 2] > -0.2]                                  # the side a scanner saw
        axes = rng.uniform(0.5, 1.0, 3)
        normals = n / axes
        trees.append(build_octree(validate(n * axes, normals), depth, neighbors=False))
    return merge_octrees(trees, neighbors=True)


def self_check(bundle_dir: Path, src: Loaded, batch: int = 3, seed: int = 0, foreground: Loaded | None = None,
               foreground_inputs: list[np.ndarray] | None = None, foreground_precision: str = "float32") -> dict:
    """Decode (classify: score) random latent codes with onnxruntime and torch; raise if they
    disagree (a guided decoder: the codes and features of :func:`probe_octrees`, encoded by both).
    Returns the figures: max |difference| of planes on the common leaves and label agreement
    (classify: of the probabilities)."""
    runtime = Runtime(load_bundle(bundle_dir), threads=1)
    latent = np.random.default_rng(seed).uniform(-1, 1, (batch, src.config.latent)).astype(np.float32)
    if src.config.task == "classify":
        ours = runtime.classify(latent)
        with torch.no_grad():
            theirs = torch.softmax(src.model.head(torch.from_numpy(latent)), 1).numpy()
        diff = float(np.abs(ours - theirs).max())
        if diff > 1e-5:
            raise BundleError(f"{bundle_dir}: onnxruntime and torch probabilities differ by {diff:.2e}")
        return {"latents": batch, "probability_max_abs_diff": diff}
    dec = src.model.decoder
    guide_a = guide_b = None
    if dec.guided:        # a guided decoder reads its input: encode real octrees with both
        octree = probe_octrees(dec.depth, batch, seed)
        latent, guide_a = runtime.encode_scan(octree)
        with torch.no_grad():
            theirs, guide_b = src.model.encode_octree(octree)
        if float(np.abs(latent - theirs.numpy()).max()) > 1e-4:
            raise BundleError(f"{bundle_dir}: onnxruntime and torch latent codes differ")
    a = runtime.decode(latent, guide=guide_a)
    b = decode(TorchSteps(dec), latent, dec.full_depth, dec.adaptive_depth, guide=guide_b)
    same = sum(int(np.sum(la.label == lb.label)) for la, lb in zip(a.levels, b.levels)
               if len(la) == len(lb) and np.array_equal(la.key, lb.key))
    total = sum(len(lb) for lb in b.levels)
    agreement = same / max(total, 1)
    plane = max((float(np.abs(la.plane - lb.plane).max()) for la, lb in zip(a.levels, b.levels)
                 if len(la) == len(lb) and len(la) and np.array_equal(la.key, lb.key)), default=0.0)
    if agreement < 0.999 or plane > 1e-4:
        raise BundleError(f"{bundle_dir}: onnxruntime and torch disagree (labels {agreement:.4%} equal, "
                          f"planes differ by up to {plane:.2e})")
    out = {"latents": batch, "label_agreement": agreement, "plane_max_abs_diff": plane, "nodes": total}
    if foreground is not None:
        out.update(foreground_check(runtime, foreground, foreground_inputs, foreground_precision))
    return out


def export(source: str | Path, out: str | Path, name: str | None = None, force: bool = False,
           foreground: str | Path | None = None, foreground_precision: str = "int8") -> dict:
    """Write the bundle of ``source`` to ``out`` (atomically); returns its model.json.  An image
    model's bundle also takes the ``foreground`` network (background removal for photos), stored
    as ``foreground_precision`` (:data:`FOREGROUND_PRECISIONS`)."""
    if foreground_precision not in FOREGROUND_PRECISIONS:
        raise BundleError(f"the foreground precision is one of {', '.join(FOREGROUND_PRECISIONS)}, "
                          f"not {foreground_precision!r}")
    out = Path(out)
    if out.exists() and not force:
        raise BundleError(f"{out}: already exists; pass --force to replace it")
    src = load_source(source)
    task = BUNDLE_TASKS[src.config.task]
    fg = None
    if foreground is not None:
        if task != "image-to-shape":
            raise BundleError(f"--foreground goes with an image model, not a {task} model")
        fg = load_foreground(foreground)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="tmp-", dir=out.parent))
    try:
        specs = {}
        graphs = export_graphs(src)
        fg_inputs = None
        if fg is not None:
            graph = G.foreground_graph(fg.model.net, fg.config.image_size)
            calibration, fg_inputs = foreground_photos(fg.config.image_size)
            if foreground_precision == "int8":
                graph = dataclasses.replace(graph, model=quantize_static_graph(
                    graph.model, [{"image": x} for x in calibration]))
            graphs.append(graph)
        for g in graphs:
            model = onnx.load_from_string(g.model)
            onnx.checker.check_model(model, full_check=True)
            path = tmp / f"{g.name}.onnx"
            write_atomic(path, g.model)
            specs[g.name] = GraphSpec(g.name, path.name, sha256_file(path), g.inputs, g.outputs).to_json()
        inp, outp = _io_spec(src, task, fg)
        meta = {
            "format": BUNDLE_FORMAT if getattr(src.model, "guided", False) else 1, "task": task, "name": name or task,
            "version": bundle_version(specs, inp, outp),
            "octree": _octree_spec(src), "input": inp, "output": outp,
            "categories": list(src.config.categories or CATEGORIES),
            "graphs": specs,
            "export": {"exporter": G.EXPORTER, "opset": G.OPSET, "torch": torch.__version__.split("+")[0],
                       "onnx": onnx.__version__, "batchnorm": "folded",
                       "quantized": ["foreground"] if fg is not None and foreground_precision == "int8" else False,
                       **({"foreground_precision": foreground_precision} if fg is not None else {})},
            "provenance": {**{k: v for k, v in src.meta.items() if k != "evaluation"},
                           **({"foreground": fg.meta} if fg is not None else {})},
            "evaluation": src.meta.get("evaluation"),
        }
        write_atomic(tmp / MANIFEST, json_text(meta).encode())
        meta["export"]["self_check"] = self_check(tmp, src, foreground=fg, foreground_inputs=fg_inputs,
                                                  foreground_precision=foreground_precision)
        write_atomic(tmp / MANIFEST, json_text(meta).encode())
        tmp.chmod(0o777 & ~UMASK)
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return meta
