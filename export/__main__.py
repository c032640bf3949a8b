"""Export a trained model to an ONNX bundle, or verify a bundle.

    python -m export CHECKPOINT_OR_RUN --out BUNDLE_DIR [--name NAME] [--force] [--foreground FG]
        [--foreground-precision int8|float32]
    python -m export --verify BUNDLE_DIR

Exit status 0 on success, 2 with one line on stderr when the input or bundle is unusable.
--verify needs onnxruntime only (no torch): it checks the manifest, every file's sha256, that
each graph loads and has the inputs and outputs model.json states, and decodes one latent code.
"""

from __future__ import annotations

import sys
from model.cli import command_parser


def verify(path: str) -> dict:
    """Load and run a bundle with onnxruntime; the figures of a successful check."""
    import time

    import numpy as np

    from .bundle import BundleError, load_bundle
    from .runtime import Runtime

    bundle = load_bundle(path)
    runtime = Runtime(bundle, threads=1)
    summary = {"task": bundle.task, "name": bundle.name, "version": bundle.version,
               "graphs": len(bundle.graphs),
               "bytes": sum(bundle.file(g).stat().st_size for g in bundle.graphs)}
    if "decoder_start" in bundle.graphs:
        t = time.perf_counter()
        octree = runtime.decode(np.zeros((1, bundle.octree.latent), np.float32))
        summary["decoded_leaves"] = sum(octree.leaves_per_depth())
        summary["decode_ms"] = round(1e3 * (time.perf_counter() - t), 1)
    if bundle.mask_spec() is not None:
        side = bundle.mask_spec().size
        mask = runtime.segment(np.full((96, 128, 3), 128, np.uint8))
        if mask.shape != (side, side) or not np.isfinite(mask).all():
            raise BundleError(f"{path}: the foreground network gives a {mask.shape} mask, not its {side}x{side} grid")
        summary["foreground"] = True
    if "classifier_head" in bundle.graphs:
        p = runtime.classify(np.zeros((1, bundle.octree.latent), np.float32))[0]
        if p.shape != (len(bundle.categories),) or abs(float(p.sum()) - 1) > 1e-4:
            raise BundleError(f"{path}: the classifier head gives {p.shape[0]} probabilities summing to "
                              f"{float(p.sum()):.4f} for {len(bundle.categories)} categories")
    return summary


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m export", __doc__, [
        "python -m export models/checkpoints/image-to-shape --out my-bundle",
        "python -m export --verify models/bundles/image-to-shape"])
    ap.add_argument("source", nargs="?", help="a checkpoint folder (model.pt + model.json) or a training run "
                    "folder (checkpoint.pt) to export")
    ap.add_argument("--out", help="the bundle folder to write (required with SOURCE)")
    ap.add_argument("--name", default=None, help="the bundle's name (default: its task)")
    ap.add_argument("--force", action="store_true", help="replace an existing bundle folder (default: refuse)")
    ap.add_argument("--foreground", default=None, metavar="FG",
                    help="image models: a foreground network's checkpoint or run folder, put in the bundle to "
                         "remove photos' backgrounds (python -m model.train foreground)")
    ap.add_argument("--foreground-precision", choices=("int8", "float32"), default="int8",
                    help="how the foreground network is stored: int8, statically quantised with generated photos "
                         "(default; 2.1x faster, the same mask IoU), or float32 as trained")
    ap.add_argument("--verify", metavar="BUNDLE_DIR", default=None, help="verify a bundle instead of exporting")
    args = ap.parse_args(argv)
    from .bundle import BundleError
    try:
        if args.verify:
            if args.source:
                ap.error("give either SOURCE --out BUNDLE_DIR or --verify BUNDLE_DIR")
            s = verify(args.verify)
            print(f"{args.verify}: OK  {s['task']} {s['name']} {s['version']}, {s['graphs']} graphs, "
                  f"{s['bytes'] / 1e6:.1f} MB" + (f", decoded {s['decoded_leaves']} patches in {s['decode_ms']} ms"
                                                  if "decode_ms" in s else ""))
            return 0
        if not args.source or not args.out:
            ap.error("SOURCE and --out are required (or --verify BUNDLE_DIR)")
        from .exporter import export
        meta = export(args.source, args.out, name=args.name, force=args.force, foreground=args.foreground,
                      foreground_precision=args.foreground_precision)
        check = meta["export"]["self_check"]
        agree = (f"probabilities within {check['probability_max_abs_diff']:.1e}" if "probability_max_abs_diff" in check
                 else f"labels {check['label_agreement']:.2%} equal, planes within {check['plane_max_abs_diff']:.1e}")
        print(f"{args.out}: {meta['task']} {meta['name']} {meta['version']}, {len(meta['graphs'])} graphs; "
              f"onnxruntime vs torch: {agree}" + (f"; foreground masks {check['foreground_pixel_agreement']:.2%} equal "
                                                   f"({meta['export']['foreground_precision']})"
                                                   if "foreground_pixel_agreement" in check else ""))
        return 0
    except (BundleError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
