"""End-to-end inference speed: onnxruntime bundles against torch eager, per stage.

For an image model (image -> shape) and an octree autoencoder / completion model (partial scan ->
shape), the same inputs go through the same pipeline twice in one process: once with the
torch checkpoint in eval mode (eager, no_grad), once with its exported bundle in onnxruntime.
Stages: preprocess (image crop/normalise, or octree build from the scan with normals estimated:
shared NumPy code), encoder, each decoder depth (predict + expand), the decode loop's NumPy
bookkeeping (decode time minus its steps), mesh output (patch mesh + GLB bytes).  Batches of 1
and 8, 1 and 2 threads; one warm-up, then the median of ``--repeats`` runs, interleaved.
onnxruntime runs with thread spinning off, as the service does.

    python -m bench.onnx_decode [--image models/checkpoints/image-to-shape]
                                [--points RUN_OR_CHECKPOINT] [--repeats 5] [--json PATH]

Inputs are procedural shapes (renders at a fixed view; partial scans from 3-5 views with holes
and noise), the same for both sides.  Bundles are exported to a temporary folder unless
``--image-bundle`` / ``--points-bundle`` name existing ones.
"""

from __future__ import annotations

import json
import statistics
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch
from PIL import Image

from bench.octree_build import table, torch_threads
from export.bundle import load_bundle
from export.exporter import export, load_source
from export.quantize import quantize
from export.runtime import Runtime
from model.cli import command_parser
from model.data.dataset import unit_mesh
from model.data.partial import partial_scan
from model.data.render import R2N2_MAX_DISTANCE, render
from model.data.shapes import CATEGORIES, generate
from model.decode import decode
from model.image.frame import prepare_image
from model.networks import TorchSteps
from model.octree import build_octree
from model.octree.batch import merge_octrees, split_octree
from model.octree.patches import patches_to_mesh

TARGET_SPEEDUP, TARGET_BOOKKEEPING = 2.0, 0.20


class TimedSteps:
    """Wraps DecoderSteps and adds each call's seconds to ``times['depth d']``."""

    def __init__(self, steps, times: dict):
        self.steps, self.times, self.depth = steps, times, steps.depth

    def classes(self, depth):
        return self.steps.classes(depth)

    def _timed(self, key, fn, *args):
        t = time.perf_counter()
        out = fn(*args)
        self.times[key] += time.perf_counter() - t
        return out

    def start(self, latent):
        return self._timed("depth 2", self.steps.start, latent)

    def predict(self, depth, x, neighbors, *skip):
        return self._timed(f"depth {depth}", self.steps.predict, depth, x, neighbors, *skip)

    def expand(self, depth, x, split):
        return self._timed(f"depth {depth}", self.steps.expand, depth, x, split)


def pipeline(kind: str, inputs: list, backend: str, model, runtime: Runtime | None, spec) -> dict:
    """Run one batch end to end (``runtime`` None: torch eager); seconds per stage."""
    times: dict = defaultdict(float)
    t0 = time.perf_counter()
    if kind == "image":
        x = np.stack([prepare_image(img, spec) for img in inputs])
    else:
        x = merge_octrees([build_octree((pts, None), spec) for pts in inputs])
    times["preprocess"] = time.perf_counter() - t0
    t = time.perf_counter()
    guide = None                 # a guided completion decoder's input features
    if runtime is not None:
        latent, guide = (runtime.encode_image(x), None) if kind == "image" else runtime.encode_scan(x)
        steps = runtime.steps()
    else:
        with torch.no_grad():
            latent, guide = (model.encoder(torch.from_numpy(x)), None) if kind == "image" else model.encode_octree(x)
        latent = latent.numpy()
        steps = TorchSteps(model.decoder)
    times["encoder"] = time.perf_counter() - t
    t = time.perf_counter()
    dec = model.decoder
    octree = decode(TimedSteps(steps, times), latent, dec.full_depth, dec.adaptive_depth, guide=guide)
    decode_s = time.perf_counter() - t
    times["bookkeeping"] = decode_s - sum(v for k, v in times.items() if k.startswith("depth"))
    t = time.perf_counter()
    for one in split_octree(octree, neighbors=False):
        patches_to_mesh(one).export(file_type="glb")
    times["mesh"] = time.perf_counter() - t
    times["total"] = time.perf_counter() - t0
    times["decode"] = decode_s
    return dict(times)


def inputs_for(kind: str, batch: int, size: int) -> list:
    """``batch`` procedural shapes of different categories: renders or partial scans."""
    out = []
    for i in range(batch):
        mesh = unit_mesh(generate(CATEGORIES[(3 * i) % len(CATEGORIES)], i))[0]
        if kind == "image":                  # as the dataset renders: 0.75 of the R2N2 distance
            rgba, _ = render(mesh, 30 + 40 * i, 25, 0.75 * R2N2_MAX_DISTANCE, size=137)
            out.append(Image.fromarray(rgba, "RGBA"))
        else:
            out.append(partial_scan(mesh, np.random.default_rng(i))[0])
    return out


def bench_model(kind: str, source: str, bundle_dir: str | None, batches, threads, repeats: int,
                int8: bool = False) -> list[dict]:
    src = load_source(source)
    tmp = tempfile.TemporaryDirectory()
    if bundle_dir is None:
        bundle_dir = f"{tmp.name}/bundle"
        export(source, bundle_dir)
    bundles = {"onnxruntime": load_bundle(bundle_dir)}
    if int8:
        quantize(bundle_dir, f"{tmp.name}/int8")
        bundles["onnxruntime int8"] = load_bundle(f"{tmp.name}/int8")
    spec = src.config.image_spec() if kind == "image" else src.config.depth
    rows = []
    for n in threads:
        # spinning off: idle onnxruntime threads would otherwise busy-wait and steal the CPU from
        # the torch runs and the other session interleaved with them (measured: 284 ms vs 8 ms)
        runtimes = {"torch": None, **{k: Runtime(v, threads=n, spinning=False) for k, v in bundles.items()}}
        with torch_threads(n):
            for b in batches:
                data = inputs_for(kind, b, src.config.image_size)
                runs: dict = {k: [] for k in runtimes}
                for r in range(repeats + 1):
                    for backend in runs:
                        res = pipeline(kind, data, backend, src.model, runtimes[backend], spec)
                        if r:
                            runs[backend].append(res)
                med = {k: {s: statistics.median(r[s] for r in v) for s in v[0]} for k, v in runs.items()}
                rows.append({"kind": kind, "batch": b, "threads": n, **med})
    tmp.cleanup()
    return rows


def model_part(stages: dict) -> float:
    """Seconds in the networks: encoder and decoder steps (what the backend changes)."""
    return stages["encoder"] + sum(v for k, v in stages.items() if k.startswith("depth"))


def report(rows: list[dict]) -> None:
    head = ["path", "batch", "thr", "torch ms", "ort ms", "speed-up", "model part t/o", "decode ms t/o",
            "bookkeeping share (ort)", "int8 ms"]
    out = []
    for r in rows:
        t, o = r["torch"], r["onnxruntime"]
        q = r.get("onnxruntime int8")
        out.append([r["kind"], r["batch"], r["threads"], f"{1e3 * t['total']:.1f}", f"{1e3 * o['total']:.1f}",
                    f"{t['total'] / o['total']:.2f}x", f"{model_part(t) / model_part(o):.2f}x",
                    f"{1e3 * t['decode']:.1f}/{1e3 * o['decode']:.1f}", f"{o['bookkeeping'] / o['decode']:.0%}",
                    f"{1e3 * q['total']:.1f}" if q else "-"])
    print(table(head, out))
    print(f"\ntargets: onnxruntime >= {TARGET_SPEEDUP:.0f}x torch eager end to end; bookkeeping <= "
          f"{TARGET_BOOKKEEPING:.0%} of the decode")
    for r in rows:
        stages = [s for s in r["onnxruntime"] if s not in ("total", "decode")]
        print(f"\n{r['kind']}, batch {r['batch']}, {r['threads']} thread(s): ms per stage")
        backends = [k for k in r if k not in ("kind", "batch", "threads")]
        print(table(["stage", *backends],
                    [[s, *[f"{1e3 * r[k].get(s, 0):.1f}" for k in backends]]
                     for s in sorted(stages, key=lambda s: (not s.startswith("pre"), s))]))


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.onnx_decode", __doc__, ['python -m bench.onnx_decode --repeats 20'])
    ap.add_argument("--image", default="models/checkpoints/image-to-shape",
                    help="image model checkpoint or run folder (default: the shipped one); '' to skip")
    ap.add_argument("--image-bundle", default=None, help="its exported bundle (default: export to a temp folder)")
    ap.add_argument("--points", default="", help="autoencoder/completion checkpoint or run folder (default: skip)")
    ap.add_argument("--points-bundle", default=None, help="its exported bundle (default: export to a temp folder)")
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 8], help="batch sizes (default 1 8)")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="thread counts (default 1 2)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per case after one warm-up (default 5)")
    ap.add_argument("--int8", action="store_true", help="also time an int8 copy of each bundle (export.quantize)")
    ap.add_argument("--json", default=None, help="also write the figures to this JSON file (default: none)")
    args = ap.parse_args(argv)
    rows = []
    if args.image:
        rows += bench_model("image", args.image, args.image_bundle, args.batches, args.threads, args.repeats,
                            args.int8)
    if args.points:
        rows += bench_model("points", args.points, args.points_bundle, args.batches, args.threads, args.repeats,
                            args.int8)
    report(rows)
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
