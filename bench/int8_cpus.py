"""The int8 foreground network on two instruction sets, per quantisation setting: this machine's
(AVX-512 with VNNI where it has it) and AVX2 without VNNI (the same machine under qemu-user's
Haswell CPU, whose cpuid onnxruntime reads to pick its kernels).

    python -m bench.int8_cpus [--checkpoint models/checkpoints/foreground] [--per-category 4]
                              [--views 2] [--json PATH]

onnxruntime's u8s8 kernels multiply-add pairs of products into 16 bits without VNNI
(``vpmaddubsw``), which saturates when both products are large; with VNNI (``vpdpbusd``) they do
not.  For each setting the float graph is quantised with the export's calibration photos
(:func:`export.exporter.foreground_photos`) and run on validation photos (the generator's
validation shapes on training backgrounds) natively and under ``qemu-x86_64 -cpu Haswell``.
Printed per setting: the mask IoU between the two CPUs on the network's grid (mean and worst
photo), the share of pixels whose logit differs, and each CPU's IoU against the exact mask.
Needs Debian's qemu-user.
"""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from model.cli import command_parser

SETTINGS = {
    "u8s8": dict(reduce_range=False),             # the export's setting before this benchmark
    "u8s8-reduce-range": dict(reduce_range=True),  # 7-bit weights: pairs of products fit in 16 bits
    "u8u8": dict(signed_weights=False),           # unsigned weights: kernels without 16-bit pair sums
}
QEMU_CPU = "Haswell"


def saturation_probe() -> int:
    """A u8 x s8 dot product of 64 elements at their largest (255 x 127): the exact sum is 2,072,640;
    kernels that add pairs of products into 16 bits give less."""
    import onnxruntime as ort
    from onnx import TensorProto, helper, numpy_helper

    w = numpy_helper.from_array(np.full((64, 1), 127, np.int8), "W")
    graph = helper.make_graph([helper.make_node("MatMulInteger", ["A", "W"], ["Y"])], "probe",
                              [helper.make_tensor_value_info("A", TensorProto.UINT8, [None, 64])],
                              [helper.make_tensor_value_info("Y", TensorProto.INT32, [None, 1])], [w])
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return int(session.run(None, {"A": np.full((4, 64), 255, np.uint8)})[0][0, 0])


def run_graphs(folder: Path, tag: str) -> None:
    """In ``folder``: every ``<setting>.onnx`` run on ``inputs.npy`` (one thread), the logits saved
    as ``<setting>.<tag>.npy``; ``probe.<tag>.json`` the saturation probe."""
    import onnxruntime as ort

    from export.runtime import session_options

    x = np.load(folder / "inputs.npy")
    for graph in sorted(folder.glob("*.onnx")):
        session = ort.InferenceSession(str(graph), session_options(1), providers=["CPUExecutionProvider"])
        logits = np.concatenate([session.run(None, {"image": x[i:i + 1]})[0] for i in range(len(x))])
        np.save(folder / f"{graph.stem}.{tag}.npy", logits)
    (folder / f"probe.{tag}.json").write_text(json.dumps({"u8s8_dot": saturation_probe()}))


def run_here_and_on_avx2(folder: Path) -> None:
    """:func:`run_graphs` on ``folder`` natively (tag ``native``) and under ``qemu-x86_64 -cpu
    Haswell`` (tag ``avx2``)."""
    cmd = [sys.executable, "-m", "bench.int8_cpus", "--run-graphs", str(folder), "--tag"]
    subprocess.run([*cmd, "native"], check=True)
    subprocess.run(["qemu-x86_64", "-cpu", QEMU_CPU, *cmd, "avx2"], check=True, stderr=subprocess.DEVNULL)


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max(1, (a | b).sum()))


def measure(checkpoint: str, per_category: int, views: int) -> dict:
    from export import graphs as G
    from export.exporter import foreground_photos, load_foreground
    from export.quantize import quantize_static_graph
    from model.data.photos import generated_photos
    from model.image.mask import mask_input, resize_mask

    if shutil.which("qemu-x86_64") is None:
        raise SystemExit("error: needs qemu-user (apt-get install qemu-user) to run the AVX2 kernels")
    fg = load_foreground(checkpoint)
    spec = _mask_spec(fg)
    size = spec.size
    graph = G.foreground_graph(fg.model.net, size)
    calibration, _ = foreground_photos(size)
    photos = generated_photos(per_category, views, seed=1, split="val")
    inputs = np.stack([mask_input(p.rgb, spec) for p in photos])
    truth = np.stack([resize_mask(p.mask, size, size) > 0.5 for p in photos])
    with tempfile.TemporaryDirectory(prefix="int8-cpus-") as tmp:
        folder = Path(tmp)
        np.save(folder / "inputs.npy", inputs)
        (folder / "float32.onnx").write_bytes(graph.model)
        for name, kw in SETTINGS.items():
            (folder / f"{name}.onnx").write_bytes(quantize_static_graph(graph.model, [{"image": x} for x in calibration],
                                                                        **kw))
        run_here_and_on_avx2(folder)
        probes = {t: json.loads((folder / f"probe.{t}.json").read_text())["u8s8_dot"] for t in ("native", "avx2")}
        rows = {}
        for name in ("float32", *SETTINGS):
            a, b = (np.load(folder / f"{name}.{t}.npy")[:, 0] for t in ("native", "avx2"))
            cross = [_iou(x > 0, y > 0) for x, y in zip(a, b)]
            rows[name] = {"iou_between_cpus_mean": float(np.mean(cross)), "iou_between_cpus_worst": float(np.min(cross)),
                          "pixels_differing": float(np.mean(a != b)),
                          "iou_truth_native": float(np.mean([_iou(x > 0, t) for x, t in zip(a, truth)])),
                          "iou_truth_avx2": float(np.mean([_iou(x > 0, t) for x, t in zip(b, truth)]))}
    return {"photos": len(photos), "size": size, "u8s8_dot_exact": 255 * 127 * 64, "u8s8_dot": probes, "settings": rows}


def _mask_spec(fg):
    from model.train.tasks import TASKS

    return TASKS["foreground"].spec(fg.config, fg.meta)


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.int8_cpus", __doc__, ["python -m bench.int8_cpus --per-category 4"])
    ap.add_argument("--checkpoint", default="models/checkpoints/foreground", help="the foreground network")
    ap.add_argument("--per-category", type=int, default=4, help="validation shapes a category")
    ap.add_argument("--views", type=int, default=2, help="photos a shape")
    ap.add_argument("--json", default=None, help="write the figures here too")
    ap.add_argument("--run-graphs", metavar="FOLDER", default=None,
                    help="(internal) run FOLDER's graphs on its inputs, as the measurement does on each CPU")
    ap.add_argument("--tag", default="native", help="(internal) with --run-graphs: the name of this CPU's outputs")
    args = ap.parse_args(argv)
    if args.run_graphs:
        run_graphs(Path(args.run_graphs), args.tag)
        return 0
    res = measure(args.checkpoint, args.per_category, args.views)
    if args.json:
        Path(args.json).write_text(json.dumps(res, indent=1))
    print(table(res))
    return 0


def table(res: dict) -> str:
    """The figures of :func:`measure` as printed."""
    lines = [f"{res['photos']} validation photos at {res['size']}^2; u8s8 dot product probe (exact "
             f"{res['u8s8_dot_exact']:,}): native {res['u8s8_dot']['native']:,}, AVX2 (qemu {QEMU_CPU}) "
             f"{res['u8s8_dot']['avx2']:,}",
             f"{'setting':20s} {'IoU CPUs mean':>13s} {'worst':>7s} {'px differ':>9s} {'IoU truth native':>16s} "
             f"{'AVX2':>7s}"]
    lines += [f"{name:20s} {r['iou_between_cpus_mean']:13.5f} {r['iou_between_cpus_worst']:7.4f} "
              f"{r['pixels_differing']:9.4f} {r['iou_truth_native']:16.4f} {r['iou_truth_avx2']:7.4f}"
              for name, r in res["settings"].items()]
    return "\n".join(lines)

if __name__ == "__main__":
    sys.exit(main())
