"""Export a trained model to an ONNX bundle, or verify a bundle.

    python -m export CHECKPOINT_OR_RUN --out BUNDLE_DIR [--name NAME] [--force] [--foreground FG]
        [--foreground-precision int8|float32]
    python -m export --verify BUNDLE_DIR [--against CHECKPOINT_OR_RUN [--foreground FG]]

Exit status 0 on success, 2 with one line on stderr when the input or bundle is unusable.
--verify needs onnxruntime only (no torch): it checks the manifest, every file's sha256, that
each graph loads and has the inputs and outputs model.json states, and runs every graph on probe
inputs (octree bundles, guided ones included: probe scans encoded and decoded; image bundles:
probe images; the foreground network: a photo), checking that the outputs are finite and the
patches' normals unit vectors.  With --against (needs torch) it also compares every graph with
the checkpoint's torch model step by step, as the export's own check does, with tolerances that
hold on every CPU.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from model.cli import command_parser
from model.octree import EMPTY

from .bundle import BundleError, load_bundle
from .parity import probe_octrees
from .runtime import Runtime

PROBES = 2
"""Probe inputs --verify runs through a bundle."""


def _check_finite(path, name: str, x: np.ndarray) -> None:
    if not np.isfinite(x).all():
        raise BundleError(f"{path}: {name} gives values that are not finite")


def _probe_latent(runtime: Runtime, path) -> tuple[np.ndarray, object]:
    """Latent codes (and a guided bundle's guide) of the bundle's encoder on probe inputs."""
    bundle = runtime.bundle
    if "image_encoder" in bundle.graphs:
        size = bundle.image_spec().size
        images = np.random.default_rng(0).normal(0, 1, (PROBES, 3, size, size)).astype(np.float32)
        latent, guide = runtime.encode_image(images), None
    else:
        o = bundle.octree
        latent, guide = runtime.encode_scan(probe_octrees(o.depth, PROBES, adaptive=o.adaptive))
        for d, f in (guide.features.items() if guide is not None else ()):
            _check_finite(path, f"the octree encoder's skip_{d}", f)
    _check_finite(path, "the encoder", latent)
    return latent, guide


def verify(path: str) -> dict:
    """Load a bundle and run every graph on probe inputs with onnxruntime; the figures of a
    successful check (BundleError when a graph fails or gives unusable outputs)."""
    bundle = load_bundle(path)
    runtime = Runtime(bundle, threads=1)
    summary = {"task": bundle.task, "name": bundle.name, "version": bundle.version,
               "graphs": len(bundle.graphs),
               "bytes": sum(bundle.file(g).stat().st_size for g in bundle.graphs)}
    latent, guide = _probe_latent(runtime, path)
    if "decoder_start" in bundle.graphs:
        t = time.perf_counter()
        octree = runtime.decode(latent, guide=guide)
        summary["decode_ms"] = round(1e3 * (time.perf_counter() - t), 1)
        summary["decoded_leaves"] = sum(octree.leaves_per_depth())
        for lv in (octree.levels[d] for d in bundle.octree.planes):
            planes = lv.plane[lv.label != EMPTY]
            _check_finite(path, f"decoder_predict_{lv.depth}", planes)
            if len(planes) and np.abs(np.linalg.norm(planes[:, :3], axis=1) - 1).max() > 1e-3:
                raise BundleError(f"{path}: decoder_predict_{lv.depth} gives patch normals that are not unit vectors")
    if bundle.mask_spec() is not None:
        side = bundle.mask_spec().size
        mask = runtime.segment(np.full((96, 128, 3), 128, np.uint8))
        if mask.shape != (side, side) or not np.isfinite(mask).all():
            raise BundleError(f"{path}: the foreground network gives a {mask.shape} mask, not its {side}x{side} grid")
        summary["foreground"] = True
        if runtime.has_refine:
            size = bundle.mask_spec().crop_size
            p = runtime.refine(np.zeros((4, size, size), np.float32))
            if p.shape != (size, size) or not np.isfinite(p).all():
                raise BundleError(f"{path}: the refinement network gives a {p.shape} mask, not its {size}x{size} grid")
    if "classifier_head" in bundle.graphs:
        p = runtime.classify(latent)
        if p.shape != (PROBES, len(bundle.categories)) or np.abs(p.sum(1) - 1).max() > 1e-4:
            raise BundleError(f"{path}: the classifier head gives {p.shape[1]} probabilities summing to "
                              f"{float(p[0].sum()):.4f} for {len(bundle.categories)} categories")
    return summary


def verify_against(path: str, source: str, foreground: str | None = None) -> dict:
    """The export's own check (:func:`export.exporter.self_check`) of a bundle against the torch
    model of ``source`` (a checkpoint or run folder; ``foreground``: the image bundle's foreground
    network's): every graph step by step."""
    try:
        # deferred: the exporter needs torch, and --verify alone runs where only onnxruntime is installed
        from .exporter import foreground_photos, load_foreground, load_source, self_check
    except ImportError as exc:
        raise BundleError(f"--against needs torch and onnx (pip install -e '.[export]'): {exc}") from None
    bundle = load_bundle(path)
    src = load_source(source)
    fg = inputs = None
    spec = bundle.meta["input"].get("foreground")
    if (foreground is not None) != (spec is not None):
        raise BundleError(f"{path}: " + ("has no foreground network to compare with --foreground" if spec is None
                                         else "has a foreground network: name its checkpoint with --foreground"))
    if foreground is not None:
        fg, inputs = load_foreground(foreground), foreground_photos(spec["size"])[1]
    precision = bundle.meta["export"].get("foreground_precision", "float32")
    return self_check(bundle.path, src, foreground=fg, foreground_inputs=inputs, foreground_precision=precision)


def _agreement(check: dict) -> str:
    """One line of a self-check's figures."""
    text = (f"{check['outputs_compared']} outputs within {check['max_relative_error']:.1e} of their magnitude "
            f"(step by step), statuses {check['lockstep_label_agreement']:.2%} alike")
    if "decode_label_agreement" in check:
        text += f", whole decodes {check['decode_label_agreement']:.2%} alike"
    if "foreground_pixel_agreement" in check:
        text += f"; foreground masks {check['foreground_pixel_agreement']:.2%} alike"
    return text


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m export", __doc__, [
        "python -m export models/checkpoints/image-to-shape --out my-bundle",
        "python -m export --verify models/bundles/image-to-shape",
        "python -m export --verify models/bundles/completion --against models/checkpoints/completion"])
    ap.add_argument("source", nargs="?", help="a checkpoint folder (model.pt + model.json) or a training run "
                    "folder (checkpoint.pt) to export")
    ap.add_argument("--out", help="the bundle folder to write (required with SOURCE)")
    ap.add_argument("--name", default=None, help="the bundle's name (default: its task)")
    ap.add_argument("--force", action="store_true", help="replace an existing bundle folder (default: refuse)")
    ap.add_argument("--foreground", default=None, metavar="FG",
                    help="image models: a foreground network's checkpoint or run folder, put in the bundle to "
                         "remove photos' backgrounds (python -m model.train foreground)")
    ap.add_argument("--refine", default=None, metavar="R",
                    help="image models, with --foreground: a refinement network's checkpoint or run folder (python -m "
                         "model.train refine), a second look at the object's square at its own resolution")
    ap.add_argument("--foreground-precision", choices=("int8", "float32"), default="int8",
                    help="how the foreground network is stored: int8, statically quantised with generated photos "
                         "(default; 2.1x faster, the same mask IoU), or float32 as trained")
    ap.add_argument("--verify", metavar="BUNDLE_DIR", default=None, help="verify a bundle instead of exporting")
    ap.add_argument("--against", metavar="CHECKPOINT", default=None,
                    help="with --verify: also compare every graph with this checkpoint's (or run's) torch model, "
                         "step by step (needs torch); an image bundle's foreground network with --foreground")
    args = ap.parse_args(argv)
    try:
        if args.verify:
            if args.source:
                ap.error("give either SOURCE --out BUNDLE_DIR or --verify BUNDLE_DIR")
            s = verify(args.verify)
            print(f"{args.verify}: OK  {s['task']} {s['name']} {s['version']}, {s['graphs']} graphs, "
                  f"{s['bytes'] / 1e6:.1f} MB" + (f", decoded {s['decoded_leaves']} patches in {s['decode_ms']} ms"
                                                  if "decode_ms" in s else ""))
            if args.against:
                check = verify_against(args.verify, args.against, args.foreground)
                print(f"{args.verify}: matches {args.against}: {_agreement(check)}")
            return 0
        if args.against:
            ap.error("--against goes with --verify BUNDLE_DIR")
        if not args.source or not args.out:
            ap.error("SOURCE and --out are required (or --verify BUNDLE_DIR)")
        from .exporter import export  # deferred: torch (see verify_against)
        meta = export(args.source, args.out, name=args.name, force=args.force, foreground=args.foreground,
                      foreground_precision=args.foreground_precision, refine=args.refine)
        print(f"{args.out}: {meta['task']} {meta['name']} {meta['version']}, {len(meta['graphs'])} graphs; "
              f"onnxruntime vs torch: {_agreement(meta['export']['self_check'])}")
        return 0
    except (ValueError, OSError) as exc:         # BundleError, and what onnxruntime or a decode refuses
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
