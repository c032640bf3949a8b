"""Checkpoint -> bundle: load a trained model, export its graphs, write and self-check the bundle.

Sources: a shipped checkpoint folder (``model.pt`` + ``model.json``, as ``model.release``
writes) or a training run folder (``checkpoint.pt``).  The bundle is written to a temporary
folder beside the target and renamed when complete, after onnxruntime has decoded a few latent
codes and matched torch (:func:`self_check`): a half-written or wrong bundle never appears.
"""

from __future__ import annotations

import dataclasses
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
from model.networks import ARCHS, OctreeDecoder, TorchSteps
from model.octree import DEFAULT_THRESHOLD
from model.preprocess import ImageSpec
from model.train.loop import TrainConfig, build_model, config_from_dict, load_checkpoint

from . import graphs as G
from .bundle import BUNDLE_FORMAT, MANIFEST, BundleError, GraphSpec, load_bundle
from .runtime import Runtime

BUNDLE_TASKS = {"image": "image-to-shape", "autoencoder": "autoencoder"}
"""Training task -> bundle task (completion and classification join with their trainings)."""
POINT_LIMITS = {"min_points": 100, "max_points": 1_000_000}


@dataclasses.dataclass
class Source:
    """A trained model ready to export: the network (eval mode), its config and its provenance."""

    model: torch.nn.Module
    config: TrainConfig
    meta: dict                  # provenance: the checkpoint folder's model.json, or the run's summary


def load_source(path: str | Path) -> Source:
    """Load a checkpoint folder (model.pt + model.json) or a run folder (checkpoint.pt)."""
    path = Path(path)
    if (path / "model.json").is_file() and (path / "model.pt").is_file():
        meta = json.loads((path / "model.json").read_text())
        digest = sha256_file(path / "model.pt")
        if meta.get("weights_sha256") not in (None, digest):
            raise BundleError(f"{path / 'model.pt'}: sha256 {digest} does not match model.json")
        cfg = config_from_dict({"data": "", "out": "", **meta["config"]})
        weights = torch.load(path / "model.pt", map_location="cpu", weights_only=True)
    elif (path / "checkpoint.pt").is_file():
        state = load_checkpoint(path / "checkpoint.pt")
        cfg, weights = config_from_dict(state["config"]), state["model"]
        meta = {"config": {k: v for k, v in state["config"].items() if k not in ("out", "progress")},
                "steps": state.get("step"), "calibration": state.get("calibration"),
                "weights_sha256": None, "source_run": str(path.resolve())}
        results = path.parent / f"{path.name}_test.json"
        if results.is_file():
            meta["evaluation"] = {k: v for k, v in json.loads(results.read_text()).items()
                                  if k not in ("per_shape", "run")}
    else:
        raise BundleError(f"{path}: neither a checkpoint folder (model.pt + model.json) nor a run (checkpoint.pt)")
    if cfg.task not in BUNDLE_TASKS:
        raise BundleError(f"{path}: task {cfg.task!r} cannot be exported; exportable: {', '.join(BUNDLE_TASKS)}")
    cfg = dataclasses.replace(cfg, teacher=None)      # the weights already hold the teacher's decoder
    model = build_model(cfg)
    model.load_state_dict(weights)
    if not isinstance(model.decoder, OctreeDecoder):
        raise BundleError(f"{path}: the {cfg.arch} decoder is a research baseline; only octree decoders export")
    return Source(model.eval(), cfg, meta)


def _octree_spec(src: Source) -> dict:
    dec: OctreeDecoder = src.model.decoder
    cfg = src.config
    adaptive = cfg.task == "image" or ARCHS[cfg.arch].octree == "adaptive"
    return {"depth": dec.depth, "full_depth": dec.full_depth, "adaptive_depth": dec.adaptive_depth,
            "adaptive": adaptive, "classes": {str(d): dec.classes(d) for d in range(dec.full_depth, dec.depth + 1)},
            "planes": [d for d in range(dec.full_depth, dec.depth + 1) if dec.has_plane(d)], "latent": cfg.latent,
            "threshold": DEFAULT_THRESHOLD if adaptive else None,
            "signal": getattr(getattr(src.model, "encoder", None), "signal", "all")}


def _io_spec(src: Source, task: str) -> tuple[dict, dict]:
    if task == "image-to-shape":
        spec = ImageSpec(size=src.config.image_size)
        inp = {"kind": "image", "image": dataclasses.asdict(spec)}
    else:
        inp = {"kind": "points", "points": {**POINT_LIMITS, "normals": "estimated when absent"}}
    return inp, {"kind": "patches", "coordinates": "unit cube [0, 1]^3 (the service maps them to the input's frame)"}


def export_graphs(src: Source) -> list[G.Graph]:
    """Every graph the bundle's task runs."""
    model, cfg = src.model, src.config
    out = G.decoder_graphs(model.decoder, cfg.latent)
    if cfg.task == "image":
        out.insert(0, G.image_encoder_graph(model.encoder, cfg.image_size, cfg.latent))
    else:
        out.insert(0, G.encoder_graph(model.encoder, cfg.latent))
    return out


def self_check(bundle_dir: Path, src: Source, batch: int = 3, seed: int = 0) -> dict:
    """Decode random latent codes with onnxruntime and torch; raise if they disagree.

    Returns the figures: max |difference| of planes on the common leaves and label agreement.
    """
    runtime = Runtime(load_bundle(bundle_dir), threads=1)
    latent = np.random.default_rng(seed).uniform(-1, 1, (batch, src.config.latent)).astype(np.float32)
    a = runtime.decode(latent)
    b = decode(TorchSteps(src.model.decoder), latent, src.model.decoder.full_depth, src.model.decoder.adaptive_depth)
    same = sum(int(np.sum(la.label == lb.label)) for la, lb in zip(a.levels, b.levels)
               if len(la) == len(lb) and np.array_equal(la.key, lb.key))
    total = sum(len(lb) for lb in b.levels)
    agreement = same / max(total, 1)
    plane = max((float(np.abs(la.plane - lb.plane).max()) for la, lb in zip(a.levels, b.levels)
                 if len(la) == len(lb) and len(la) and np.array_equal(la.key, lb.key)), default=0.0)
    if agreement < 0.999 or plane > 1e-4:
        raise BundleError(f"{bundle_dir}: onnxruntime and torch disagree (labels {agreement:.4%} equal, "
                          f"planes differ by up to {plane:.2e})")
    return {"latents": batch, "label_agreement": agreement, "plane_max_abs_diff": plane, "nodes": total}


def export(source: str | Path, out: str | Path, name: str | None = None, force: bool = False) -> dict:
    """Write the bundle of ``source`` to ``out`` (atomically); returns its model.json."""
    out = Path(out)
    if out.exists() and not force:
        raise BundleError(f"{out}: already exists; pass --force to replace it")
    src = load_source(source)
    task = BUNDLE_TASKS[src.config.task]
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix="tmp-", dir=out.parent))
    try:
        specs = {}
        for g in export_graphs(src):
            model = onnx.load_from_string(g.model)
            onnx.checker.check_model(model, full_check=True)
            path = tmp / f"{g.name}.onnx"
            write_atomic(path, g.model)
            specs[g.name] = GraphSpec(g.name, path.name, sha256_file(path), g.inputs, g.outputs).to_json()
        inp, outp = _io_spec(src, task)
        weights = src.meta.get("weights_sha256")
        meta = {
            "format": BUNDLE_FORMAT, "task": task, "name": name or task,
            "version": f"{importlib.metadata.version('adaptive-ocnn')}+{(weights or specs['decoder_start']['sha256'])[:12]}",
            "octree": _octree_spec(src), "input": inp, "output": outp,
            "categories": list(src.config.categories or CATEGORIES),
            "graphs": specs,
            "export": {"exporter": G.EXPORTER, "opset": G.OPSET, "torch": torch.__version__.split("+")[0],
                       "onnx": onnx.__version__, "batchnorm": "folded", "quantized": False},
            "provenance": {k: v for k, v in src.meta.items() if k != "evaluation"},
            "evaluation": src.meta.get("evaluation"),
        }
        write_atomic(tmp / MANIFEST, json_text(meta).encode())
        meta["export"]["self_check"] = self_check(tmp, src)
        write_atomic(tmp / MANIFEST, json_text(meta).encode())
        tmp.chmod(0o777 & ~UMASK)
        if out.exists():
            shutil.rmtree(out)
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return meta
