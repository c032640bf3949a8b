"""One training step of Adaptive O-CNN vs O-CNN on the same shapes: time and peak memory.

For each depth, the same shapes (procedural, one per category, virtual scans) give adaptive
and full octrees; ``aocnn`` trains on the adaptive ones and ``ocnn-patch`` on the full ones
(encoder + decoder, forward + backward + optimiser step, batch --batch).  Each configuration
runs in a fresh process so that its peak resident memory (ru_maxrss) is its own.  The paper
reports about 4.5x less time and 73% less memory at 256^3.

    python -m bench.train_step [--task autoencoder|classify] [--depths 6 7 8] [--batch 8] [--steps 5] [--threads N]

``--task classify`` compares the classifiers (encoder + FC head, cross-entropy) as the paper's
Table 1 does (its ModelNet40 figures at depths 5-7: Adaptive O-CNN faster and leaner).
"""

from __future__ import annotations

import argparse
import json
import resource
import subprocess
import sys
import time
from typing import TYPE_CHECKING

import numpy as np

from model.cli import command_parser

if TYPE_CHECKING:
    from model.nn.tensors import OctreeTensors


TASKS = {"autoencoder": ("aocnn", "ocnn-patch"), "classify": ("aocnn", "ocnn")}
"""--task -> (Adaptive O-CNN arch, O-CNN arch) compared."""


def training_batch(adaptive: bool, depth: int, batch: int) -> OctreeTensors:
    """The octree tensors of ``batch`` procedural shapes, one per category in turn (shape i has
    seed i), virtually scanned: adaptive or full octrees of ``depth``, merged into one batch."""
    from model.data import generate, scan
    from model.data.shapes import CATEGORIES
    from model.nn.tensors import OctreeTensors
    from model.octree import build_octree
    from model.octree.batch import merge_octrees

    trees = []
    for i in range(batch):
        pts, nrm = scan(generate(CATEGORIES[i % len(CATEGORIES)], i), resolution=256)
        trees.append(build_octree((pts, nrm), depth, adaptive=adaptive))
    return OctreeTensors.from_octree(merge_octrees(trees))


def measure(task: str, arch: str, depth: int, batch: int, steps: int, threads: int | None) -> dict:
    """Runs in a child process: median step time and peak memory of one configuration."""
    import torch

    from model.data.shapes import CATEGORIES
    from model.networks import ARCHS, CLASSIFIER_ARCHS, Autoencoder, Classifier

    if threads:
        torch.set_num_threads(threads)
    kind = ARCHS[arch].octree if task == "autoencoder" else CLASSIFIER_ARCHS[arch][0]
    octree = training_batch(kind == "adaptive", depth, batch)
    torch.manual_seed(0)
    if task == "autoencoder":
        model = Autoencoder(arch, depth, base_channels=8)
        args: tuple = (octree,)
    else:
        model = Classifier(arch, depth, len(CATEGORIES), base_channels=8)
        args = (octree, torch.arange(batch) % len(CATEGORIES))
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    times = []
    for _ in range(steps + 1):
        t = time.perf_counter()
        loss = model(*args)["total"]
        opt.zero_grad()
        loss.backward()
        opt.step()
        times.append(time.perf_counter() - t)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return {"arch": arch, "depth": depth, "nodes": int(sum(len(lv.label) for lv in octree.levels)),
            "seconds": float(np.median(times[1:])), "peak_mb": peak / 1024, "step_mb": (peak - base) / 1024}


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.train_step", __doc__, [
        "python -m bench.train_step --depths 5 6 7 --task classify"])
    ap.add_argument("--depths", type=int, nargs="+", default=[6, 7, 8], help="octree depths (default 6 7 8)")
    ap.add_argument("--batch", type=int, default=8, help="shapes per step, one per category in turn (default 8)")
    ap.add_argument("--steps", type=int, default=5, help="timed steps after a warm-up, median taken (default 5)")
    ap.add_argument("--threads", type=int, default=None, help="torch threads (default: torch's)")
    ap.add_argument("--task", choices=sorted(TASKS), default="autoencoder",
                    help="autoencoder (aocnn vs ocnn-patch, default) or classify (aocnn vs ocnn: paper Table 1)")
    ap.add_argument("--child", nargs=2, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        print(json.dumps(measure(args.task, args.child[0], int(args.child[1]), args.batch, args.steps, args.threads)))
        return 0
    ours, theirs = TASKS[args.task]
    print(f"{args.task}, batch {args.batch}, median of {args.steps} steps after a warm-up, one process per row")
    print(f"{'depth':>5} {'arch':>10} {'nodes':>9} {'step s':>8} {'peak MB':>8} {'step MB':>8}")
    for depth in args.depths:
        res = {}
        for arch in (ours, theirs):
            cmd = [sys.executable, "-m", "bench.train_step", "--task", args.task, "--child", arch, str(depth),
                   "--batch", str(args.batch), "--steps", str(args.steps)]
            if args.threads:
                cmd += ["--threads", str(args.threads)]
            out = subprocess.run(cmd, capture_output=True, text=True, check=True).stdout
            r = res[arch] = json.loads(out.strip().splitlines()[-1])
            print(f"{depth:>5} {arch:>10} {r['nodes']:>9} {r['seconds']:>8.3f} {r['peak_mb']:>8.0f} {r['step_mb']:>8.0f}")
        a, f = res[ours], res[theirs]
        print(f"{depth:>5} {'ratio':>10} {a['nodes'] / f['nodes']:>9.3f} {a['seconds'] / f['seconds']:>8.3f} "
              f"{a['peak_mb'] / f['peak_mb']:>8.3f} {a['step_mb'] / max(f['step_mb'], 1e-9):>8.3f}")
    if args.task == "autoencoder":
        print("targets at depth 8 (spec): time <= 0.35, peak memory <= 0.4")
    return 0


if __name__ == "__main__":
    sys.exit(main())
