"""int8 quantisation: dynamic, of a bundle's graphs (a measurement tool), and static, of one graph
with calibration inputs (what the export does to the foreground network).

    python -m export.quantize BUNDLE_DIR --out QUANTIZED_DIR [--graphs encoder|decoder|all]

Writes a copy of the bundle with the chosen graphs quantised by
``onnxruntime.quantization.quantize_dynamic`` (MatMul/Gemm and Conv weights, signed int8) and
model.json updated (checksums, ``export.quantized``).  Whether it pays is measured, not assumed:
``bench.onnx_decode`` for speed and ``research.evaluate --bundle`` for the Chamfer distance.  (The
encoders' convolutions become ``ConvInteger`` that way, slower than float32 in onnxruntime; static
quantisation, :func:`quantize_static_graph`, gives ``QLinearConv``-able QDQ pairs instead.)
"""

from __future__ import annotations

import json
import logging
import shutil
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper
from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_dynamic, quantize_static

from model.cli import command_parser
from model.files import json_text, sha256_file, write_atomic

from .bundle import MANIFEST, BundleError, load_bundle

GROUPS = {"encoder": ("image_encoder", "octree_encoder"), "decoder": ("decoder_",), "all": ("",)}


def quantize(bundle_dir: str | Path, out: str | Path, group: str = "all") -> list[str]:
    """Write the quantised copy; returns the names of the quantised graphs."""

    bundle = load_bundle(bundle_dir)
    out = Path(out)
    if out.exists():
        raise BundleError(f"{out}: already exists")
    tmp = Path(tempfile.mkdtemp(prefix="tmp-", dir=out.parent))
    try:
        meta = json.loads((bundle.path / MANIFEST).read_text())
        done = []
        for name, spec in bundle.graphs.items():
            target = tmp / spec.file
            if name.startswith(GROUPS[group]):
                quantize_dynamic(bundle.file(name), target, weight_type=QuantType.QInt8)
                done.append(name)
            else:
                shutil.copy(bundle.file(name), target)
            meta["graphs"][name]["sha256"] = sha256_file(target)
        meta["export"]["quantized"] = done
        meta["version"] += "-int8"
        write_atomic(tmp / MANIFEST, json_text(meta).encode())
        tmp.rename(out)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return done


def quantize_static_graph(model: bytes, calibration: list[dict[str, np.ndarray]], reduce_range: bool = False,
                          signed_weights: bool = True) -> bytes:
    """The graph ``model`` statically quantised to int8 in QDQ form: weights signed int8 per output
    channel (``reduce_range``: 7 bits; ``signed_weights`` False: unsigned), activations unsigned int8
    with ranges (min-max) observed on the ``calibration`` input feeds.  onnxruntime's CPU provider
    runs the quantised convolutions as int8 kernels."""

    if not calibration:
        raise BundleError("static quantisation needs at least one calibration input")

    class Feeds(CalibrationDataReader):
        def __init__(self):
            self.feeds = iter(calibration)

        def get_next(self):
            return next(self.feeds, None)

    with tempfile.TemporaryDirectory(prefix="quantize-") as tmp:
        src, dst = Path(tmp) / "float.onnx", Path(tmp) / "int8.onnx"
        src.write_bytes(model)
        previous = logging.root.manager.disable
        logging.disable(logging.WARNING)      # its advice to pre-process (shape inference; BN is already folded)
        try:
            quantize_static(src, dst, Feeds(), quant_format=QuantFormat.QDQ, per_channel=True,
                            reduce_range=reduce_range, activation_type=QuantType.QUInt8,
                            weight_type=QuantType.QInt8 if signed_weights else QuantType.QUInt8)
        finally:
            logging.disable(previous)
        return dst.read_bytes()


def output_range(model: bytes, output: str) -> tuple[float, float, float]:
    """(step, lowest, highest): the quantisation step of a QDQ graph's float ``output`` and the
    range its int8 values can express (the DequantizeLinear that gives it); BundleError when the
    output is not dequantised from int8."""

    graph = onnx.load_from_string(model).graph
    init = {t.name: numpy_helper.to_array(t) for t in graph.initializer}
    node = next((n for n in graph.node if output in n.output), None)
    if node is None or node.op_type != "DequantizeLinear" or node.input[1] not in init:
        raise BundleError(f"the graph's output {output!r} is not dequantised from int8")
    scale = float(init[node.input[1]])
    zero = init[node.input[2]] if len(node.input) > 2 and node.input[2] in init else np.zeros((), np.uint8)
    info = np.iinfo(zero.dtype)
    return scale, scale * (info.min - float(zero)), scale * (info.max - float(zero))


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m export.quantize", __doc__, [
        "python -m export.quantize models/bundles/image-to-shape --out q-bundle --graphs encoder"])
    ap.add_argument("bundle", help="the bundle folder to quantise")
    ap.add_argument("--out", required=True, help="the quantised bundle folder to write")
    ap.add_argument("--graphs", choices=sorted(GROUPS), default="all", help="which graphs (default all)")
    args = ap.parse_args(argv)
    try:
        done = quantize(args.bundle, args.out, args.graphs)
    except (BundleError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {len(done)} graphs quantised to int8")
    return 0


if __name__ == "__main__":
    sys.exit(main())
