"""Checkpoint -> bundle: load a trained model, export its graphs, write and self-check the bundle.

Loadeds: a shipped checkpoint folder (``model.pt`` + ``model.json``, as ``research.release``
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

from model.checkpoint import Loaded, load_model
from model.data.photos import generated_photos
from model.data.shapes import CATEGORIES
from model.files import UMASK, json_text, sha256_file, write_atomic
from model.image.mask import MaskSpec, NoObjectError, crop_input, mask_bounds, mask_input, object_mask, object_square
from model.networks import ARCHS, CLASSIFIER_ARCHS, OctreeDecoder, TorchSteps
from model.networks.foreground import torch_segment
from model.nn.tensors import OctreeTensors
from model.octree import DEFAULT_THRESHOLD
from model.octree.pointcloud import SCAN_FRAME_MARGIN
from model.train.tasks import TASKS

from . import graphs as G
from .bundle import BUNDLE_FORMAT, BUNDLE_TASKS, MANIFEST, BundleError, GraphSpec, Task, load_bundle
from .parity import RELATIVE_TOLERANCE, ParityReport, decoder_parity, probe_octrees, relative_error
from .quantize import output_range, quantize_static_graph
from .runtime import Runtime

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


def _load_task(path: str | Path, task: str, what: str) -> Loaded:
    """A trained run or checkpoint folder of the given training task; BundleError otherwise."""
    try:
        loaded = load_model(path)
    except ValueError as exc:
        raise BundleError(str(exc)) from None
    if loaded.config.task != task:
        raise BundleError(f"{path}: a {loaded.config.task} run, not {what}")
    return loaded


def load_foreground(path: str | Path) -> Loaded:
    """A trained foreground network (run or checkpoint folder) to put in an image bundle."""
    return _load_task(path, "foreground", "a foreground network")


def _io_spec(src: Loaded, task: str, foreground: Loaded | None = None, refine: Loaded | None = None
             ) -> tuple[dict, dict]:
    if task == Task.IMAGE_TO_SHAPE:
        spec = src.config.image_spec()
        inp = {"kind": "image", "image": dataclasses.asdict(spec)}
        if foreground is not None:
            mask = TASKS["foreground"].spec(foreground.config, foreground.meta)
            if refine is not None:
                mask = dataclasses.replace(mask, crop_size=refine.config.image_size)
            inp["foreground"] = mask.to_dict()
    else:
        inp = {"kind": "points", "points": {**POINT_LIMITS, "normals": "estimated when absent"}}
        if task == Task.COMPLETION:
            inp["points"]["frame"] = {"function": "model.octree.scan_frame", "margin": SCAN_FRAME_MARGIN}
        if task == Task.CLASSIFY:
            inp["points"]["up"] = src.config.up
    if task == Task.CLASSIFY:
        return inp, {"kind": "probabilities", "classes": list(src.config.categories)}
    out = {"kind": "patches", "coordinates": "unit cube [0, 1]^3 (the service maps them to the input's frame)"}
    if task == Task.COMPLETION and src.meta.get("keep_scan"):
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
in onnxruntime, the same mask IoU, docs/journal/2026-11-experiments.md) or as trained."""
FOREGROUND_INT8 = "u8 activations, s8 per-channel weights in 7 bits (reduce_range)"
"""The int8 form: 7-bit weights keep every pair of u8 x s8 products within the 16 bits that
onnxruntime's kernels without VNNI add them in, so AVX2 and AVX-512 VNNI machines give the same
masks bit for bit (8-bit weights: 0.993 mean IoU between the two, 0.933 on the worst photo; the
same speed; python -m bench.int8_cpus, docs/export.md)."""

FOREGROUND_INT8_AGREEMENT = 0.99
"""The share of mask pixels (logit > 0) an int8 foreground graph must agree on with torch, on
photos it was not calibrated with (a quantisation-quality bound, far below what differing CPUs move:
they flip a few pixels whose logits are within a quantisation step of 0)."""
FOREGROUND_INT8_STEPS = 12.0
"""The largest difference, in the int8 graph's output quantisation steps, allowed between its
logits and torch's (clipped to the int8 output's range) at the 99th percentile of pixels."""


def foreground_photos(size: int, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Calibration and check inputs of a foreground network, (1, 3, size, size) each: the
    generator's training shapes photographed (:func:`model.data.photos.generated_photos`), every
    other photo in each list."""

    spec = MaskSpec(size=size)
    inputs = [mask_input(p.rgb, spec)[None] for p in generated_photos(per_category=2, views=2, seed=seed)]
    return inputs[::2], inputs[1::2]


def foreground_check(runtime: Runtime, foreground: Loaded, photos: list[np.ndarray], precision: str,
                     graph: str = "foreground") -> dict:
    """onnxruntime's and torch's foreground logits of ``photos`` (network inputs): raise BundleError
    if they disagree beyond the ``precision``'s allowance.  float32: within
    :data:`export.parity.RELATIVE_TOLERANCE` of the logits' magnitude.  int8: compared with torch's
    logits clipped to the range the int8 output can hold, in units of its quantisation step
    (:func:`export.quantize.output_range`): the 99th percentile within
    :data:`FOREGROUND_INT8_STEPS`, and the mask (logit > 0) the same on
    :data:`FOREGROUND_INT8_AGREEMENT` of the pixels.  ``graph``: the foreground graph checked
    (``foreground_refine``: the refinement network, its figures' keys prefixed ``refine_``)."""
    ours = np.concatenate([runtime.run(graph, {"image": x})[0] for x in photos])
    with torch.no_grad():
        theirs = foreground.model.net(torch.from_numpy(np.concatenate(photos))).numpy()
    agree = float(np.mean((ours > 0) == (theirs > 0)))
    key = "foreground" if graph == "foreground" else "refine"
    out = {f"{key}_pixel_agreement": agree}
    if precision == "float32":
        out[f"{key}_relative_error"] = error = relative_error(theirs, ours)
        if not error <= RELATIVE_TOLERANCE:
            raise BundleError(f"onnxruntime and torch {graph} logits differ by {error:.2e} of their magnitude "
                              f"(tolerance {RELATIVE_TOLERANCE:.0e})")
        return out
    step, lo, hi = output_range(runtime.bundle.file(graph).read_bytes(), "logits")
    steps = float(np.quantile(np.abs(ours - np.clip(theirs, lo, hi)), 0.99) / step)
    out.update({f"{key}_int8_steps_p99": steps, f"{key}_output_step": step})
    if agree < FOREGROUND_INT8_AGREEMENT or steps > FOREGROUND_INT8_STEPS:
        raise BundleError(f"onnxruntime (int8) and torch {graph} logits differ by {steps:.1f} quantisation steps "
                          f"at the 99th percentile (at most {FOREGROUND_INT8_STEPS:g}); {agree:.4%} of the mask's "
                          f"pixels agree (at least {FOREGROUND_INT8_AGREEMENT:.0%})")
    return out


def load_refine(path: str | Path) -> Loaded:
    """A trained refinement network (run or checkpoint folder) to put in an image bundle."""
    return _load_task(path, "refine", "a refinement network (python -m model.train refine)")


def refine_inputs(foreground: Loaded, size: int, seed: int = 0) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Calibration and check inputs of a refinement network, (1, 4, size, size) each: the photos of
    :func:`foreground_photos`, each cut about the first network's mask (in torch) as the service
    cuts it (:func:`model.image.mask.crop_input`), every other one in each list."""
    spec = dataclasses.replace(TASKS["foreground"].spec(foreground.config, foreground.meta), crop_size=size)
    segment = torch_segment(foreground.model.net.eval(), spec)
    inputs = []
    for p in generated_photos(per_category=2, views=2, seed=seed):
        try:
            first = object_mask(p.rgb, segment, spec)
        except NoObjectError:
            continue
        h, w = first.shape
        inputs.append(crop_input(p.rgb, first, object_square(mask_bounds(first > 0.5), h, w, spec.crop_margin),
                                 spec)[None])
    return inputs[::2], inputs[1::2]


def _foreground_graphs(fg: Loaded | None, ref: Loaded | None, precision: str, graphs: list) -> list:
    """Append the foreground network's graph (and the refinement's) to ``graphs``, in int8 when
    ``precision`` says so (calibrated on photos the export makes); returns what to check each
    with: (graph name, the network in torch, check inputs)."""
    checks = []
    for loaded, name, channels, make in ((fg, "foreground", 3, foreground_photos),
                                         (ref, "foreground_refine", 4, lambda size: refine_inputs(fg, size))):
        if loaded is None:
            continue
        graph = G.foreground_graph(loaded.model.net, loaded.config.image_size, channels, name)
        calibration, inputs = make(loaded.config.image_size)
        if precision == "int8":
            graph = dataclasses.replace(graph, model=quantize_static_graph(
                graph.model, [{"image": x} for x in calibration], reduce_range=True))
        graphs.append(graph)
        checks.append((name, loaded, inputs))
    return checks


def bundle_version(graphs: dict[str, dict], inp: dict, outp: dict) -> str:
    """The package's version and a digest of what a bundle serves: every graph (its sha256) and the
    input and output settings (the preprocessing, the foreground network's mask settings, the decode
    settings), so that anything that changes an answer changes the version."""
    served = {"graphs": {name: g["sha256"] for name, g in sorted(graphs.items())}, "input": inp, "output": outp}
    return f"{importlib.metadata.version('adaptive-ocnn')}+{hashlib.sha256(json_text(served).encode()).hexdigest()[:12]}"


def _parity(runtime: Runtime, src: Loaded, report: ParityReport, batch: int, seed: int) -> None:
    """Every graph of ``src``'s bundle against torch, in ``report``: the encoder on
    :func:`probe_octrees` (image models: random images), then the decoder in lockstep
    (:func:`export.parity.decoder_parity`) on random latent codes, or a guided decoder on the
    probe octrees' own codes and features as each implementation encoded them."""
    model, cfg = src.model, src.config
    rng = np.random.default_rng(seed)
    latent = rng.uniform(-1, 1, (batch, cfg.latent)).astype(np.float32)
    guides = other_latent = None
    with torch.no_grad():
        if cfg.task == "image":
            images = rng.normal(0, 1, (batch, 3, cfg.image_size, cfg.image_size)).astype(np.float32)
            report.compare("image_encoder/latent", model.encoder(torch.from_numpy(images)), runtime.encode_image(images))
        else:
            spec = _octree_spec(src)
            octree = probe_octrees(spec["depth"], batch, seed, adaptive=spec["adaptive"])
            ours, guide_o = runtime.encode_scan(octree)
            theirs, guide_t = (model.encode_octree(octree) if hasattr(model, "encode_octree")
                               else (model.encoder(OctreeTensors.from_octree(octree)), None))
            report.compare("octree_encoder/latent", theirs, ours)
            for d in sorted(guide_o.features) if guide_o is not None else ():
                report.compare(f"octree_encoder/skip_{d}", guide_t.features[d], guide_o.features[d])
            if guide_o is not None:
                latent, other_latent, guides = theirs.numpy(), ours, (guide_t, guide_o)
        if cfg.task == "classify":
            report.compare("classifier_head/probabilities", torch.softmax(model.head(torch.from_numpy(latent)), 1),
                           runtime.classify(latent))
            return
    dec = model.decoder
    decoder_parity(TorchSteps(dec), runtime.steps(), latent, dec.full_depth, dec.adaptive_depth, report,
                   other_latent=other_latent, guides=guides)


def self_check(bundle_dir: Path, src: Loaded, batch: int = 3, seed: int = 0, foreground: Loaded | None = None,
               foreground_inputs: list[np.ndarray] | None = None, foreground_precision: str = "float32",
               runtime: Runtime | None = None) -> dict:
    """Run every graph of the bundle in onnxruntime and in torch on the same inputs and compare
    them step by step (:func:`_parity`, tolerance :data:`export.parity.RELATIVE_TOLERANCE`):
    raise BundleError naming the first output that differs.  Which way near-tied statuses went
    is reported, not checked (it may differ between CPUs).  Returns the figures."""
    runtime = runtime or Runtime(load_bundle(bundle_dir), threads=1)
    if runtime.bundle.task != BUNDLE_TASKS[src.config.task]:
        raise BundleError(f"{bundle_dir}: a {runtime.bundle.task} bundle, not the export of a "
                          f"{BUNDLE_TASKS[src.config.task]} model")
    report = ParityReport()
    _parity(runtime, src, report, batch, seed)
    if not report.ok:
        raise BundleError(f"{bundle_dir}: onnxruntime and torch disagree: {report.summary()}")
    out = {"inputs": batch, **report.to_dict()}
    if foreground is not None:
        out.update(foreground_check(runtime, foreground, foreground_inputs, foreground_precision))
    return out


def export(source: str | Path, out: str | Path, name: str | None = None, force: bool = False,
           foreground: str | Path | None = None, foreground_precision: str = "int8",
           refine: str | Path | None = None) -> dict:
    r"""Write the bundle of ``source`` to ``out`` (atomically); returns its model.json.  An image
    model's bundle also takes the ``foreground`` network (background removal for photos) and its
    ``refine``\ ment network (a second look at the object's square), both stored as
    ``foreground_precision`` (:data:`FOREGROUND_PRECISIONS`)."""
    if foreground_precision not in FOREGROUND_PRECISIONS:
        raise BundleError(f"the foreground precision is one of {', '.join(FOREGROUND_PRECISIONS)}, "
                          f"not {foreground_precision!r}")
    out = Path(out)
    if out.exists() and not force:
        raise BundleError(f"{out}: already exists; pass --force to replace it")
    src = load_source(source)
    task = BUNDLE_TASKS[src.config.task]
    fg = ref = None
    if foreground is not None:
        if task != Task.IMAGE_TO_SHAPE:
            raise BundleError(f"--foreground goes with an image model, not a {task} model")
        fg = load_foreground(foreground)
    if refine is not None:
        if fg is None:
            raise BundleError("--refine goes with --foreground (it refines the foreground network's mask)")
        ref = load_refine(refine)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="tmp-", dir=out.parent))
    try:
        specs = {}
        graphs = export_graphs(src)
        checks = _foreground_graphs(fg, ref, foreground_precision, graphs)
        for g in graphs:
            model = onnx.load_from_string(g.model)
            onnx.checker.check_model(model, full_check=True)
            path = tmp / f"{g.name}.onnx"
            write_atomic(path, g.model)
            specs[g.name] = GraphSpec(g.name, path.name, sha256_file(path), g.inputs, g.outputs).to_json()
        inp, outp = _io_spec(src, task, fg, ref)
        meta = {
            "format": BUNDLE_FORMAT if getattr(src.model, "guided", False) else 1, "task": task, "name": name or task,
            "version": bundle_version(specs, inp, outp),
            "octree": _octree_spec(src), "input": inp, "output": outp,
            "categories": list(src.config.categories or CATEGORIES),
            "graphs": specs,
            "export": {"exporter": G.EXPORTER, "opset": G.OPSET, "torch": torch.__version__.split("+")[0],
                       "onnx": onnx.__version__, "batchnorm": "folded",
                       "quantized": [name for name, _, _ in checks] if checks and foreground_precision == "int8"
                       else False,
                       **({"foreground_precision": foreground_precision} if fg is not None else {}),
                       **({"foreground_int8": FOREGROUND_INT8} if fg is not None and foreground_precision == "int8"
                          else {})},
            "provenance": {**{k: v for k, v in src.meta.items() if k != "evaluation"},
                           **({"foreground": fg.meta} if fg is not None else {}),
                           **({"foreground_refine": ref.meta} if ref is not None else {})},
            "evaluation": src.meta.get("evaluation"),
        }
        write_atomic(tmp / MANIFEST, json_text(meta).encode())
        meta["export"]["self_check"] = check = self_check(tmp, src)
        runtime = Runtime(load_bundle(tmp), threads=1)
        for graph_name, net, inputs in checks:
            check.update(foreground_check(runtime, net, inputs, foreground_precision, graph_name))
        write_atomic(tmp / MANIFEST, json_text(meta).encode())
        tmp.chmod(0o777 & ~UMASK)
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return meta
