"""Octree convolution speed: ours (``model.nn.octree_conv``) against ``ocnn`` and the bare GEMMs.

``--points`` (default 100k) oriented points are sampled from a mesh (area-weighted, seed 0) and the
full (O-CNN) octree of depth ``--depth`` (default 7) is built by both libraries from the same
unit-cube coordinates.  A 3x3x3 convolution, ``--channels`` in and out (default 32), float32, over
all nodes of the max depth is timed forward + backward (grad of input and weight), in one process,
interleaved run by run (one warm-up round, then the median of ``--repeats`` rounds), at torch's
default thread count and at 1 thread:

* ours               -- ``OctreeConv`` (row-chunked gather + GEMM, the kept formulation)
* ours, one gather   -- the same op with all rows in one chunk (the graph-capture formulation)
* 27 gathers+GEMMs   -- the per-offset alternative (27 gathers, 27 accumulated GEMMs)
* ocnn explicit_gemm / block_gemm -- ``ocnn.nn.OctreeConv(C, C, [3], 1, nempty=False, method=...)``
* bare GEMM (fresh)  -- forward (N, 27C) @ (27C, C), backward (N, C) @ (C, 27C) and
  (27C, N) @ (N, C) on a prepared column matrix, outputs allocated by ``torch.mm``
* bare GEMM (out=)   -- the same three products into preallocated outputs: the compute bound

Forward only (no autograd) is timed too.  Ours and ocnn are also checked to give the same output
with the same weights.  Run from the repository root::

    python -m bench.conv [--depth 7] [--points 100000] [--channels 32] [--repeats 7]
                         [--mesh stanford_bunny.obj] [--mesh-dir DIR] [--json PATH]
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import sys
import time
from dataclasses import dataclass
from typing import Callable

import numpy as np
import torch

from bench.octree_build import DEFAULT_MESH_DIR, import_ocnn, ocnn_inputs, sample_points, table, torch_threads
from model.cli import command_parser
from model.nn import OctreeConv, octree_conv
from model.octree import build_octree

OURS, ONE, PER_OFFSET = "ours", "ours, one gather", "27 gathers+GEMMs"
OCNN_EXPLICIT, OCNN_BLOCK = "ocnn explicit_gemm", "ocnn block_gemm"
BARE, BARE_OUT = "bare GEMM (fresh)", "bare GEMM (out=)"
TARGET_OCNN, TARGET_BARE = 0.5, 1.3


@dataclass
class Case:
    """A timed configuration: ``run(backward)`` does one forward (+ backward) pass."""

    name: str
    run: Callable[[bool], None]


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = command_parser("python -m bench.conv", __doc__, ['python -m bench.conv --depth 7 --channels 32'])
    p.add_argument("--depth", type=int, default=7, help="octree depth (default 7)")
    p.add_argument("--points", type=int, default=100_000, help="points sampled from the mesh (default 100000)")
    p.add_argument("--channels", type=int, default=32, help="input and output channels (default 32)")
    p.add_argument("--repeats", type=int, default=7, help="timed rounds; the median is reported (default 7)")
    p.add_argument("--mesh", default="stanford_bunny.obj", help="mesh file in --mesh-dir (default stanford_bunny.obj)")
    p.add_argument("--mesh-dir", default=DEFAULT_MESH_DIR,
                    help="folder of the meshes (default: ../shared/meshes beside the checkout)")
    p.add_argument("--json", metavar="PATH", help="also write a JSON summary here")
    return p.parse_args(argv)


def per_offset_conv(x: torch.Tensor, neighbors: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """The measured alternative: one (N, Cin) gather and one accumulated GEMM per kernel offset."""
    padded = torch.cat([x.new_zeros(1, x.shape[1]), x])
    index = (neighbors + 1).t().contiguous()
    out = padded.index_select(0, index[0]).mm(weight[0])
    for k in range(1, 27):
        out = out.addmm(padded.index_select(0, index[k]), weight[k])
    return out


def autograd_case(name: str, forward: Callable[[torch.Tensor], torch.Tensor], x0: torch.Tensor,
                  grad: torch.Tensor, params: list[torch.Tensor]) -> Case:
    """Forward from a fresh leaf copy of ``x0``; backward with ``grad``; parameter grads reset."""
    def run(backward: bool) -> None:
        for p in params:
            p.grad = None
        if not backward:
            with torch.no_grad():
                forward(x0)
            return
        x = x0.detach().requires_grad_()
        forward(x).backward(grad)
    return Case(name, run)


def bare_cases(n: int, c: int, grad: torch.Tensor) -> list[Case]:
    col = torch.randn(n, 27 * c)
    w = torch.randn(27 * c, c)
    out, gcol, gw = torch.empty(n, c), torch.empty(n, 27 * c), torch.empty(27 * c, c)

    def fresh(backward: bool) -> None:
        col.mm(w)
        if backward:
            grad.mm(w.t())
            col.t().mm(grad)

    def preallocated(backward: bool) -> None:
        torch.mm(col, w, out=out)
        if backward:
            torch.mm(grad, w.t(), out=gcol)
            torch.mm(col.t(), grad, out=gw)
    return [Case(BARE, fresh), Case(BARE_OUT, preallocated)]


def time_cases(cases: list[Case], repeats: int, threads: int, backward: bool) -> dict[str, float]:
    """Median ms per case: one warm-up round, then ``repeats`` rounds running each case once."""
    times: dict[str, list[float]] = {c.name: [] for c in cases}
    with torch_threads(threads):
        for rnd in range(repeats + 1):
            for case in cases:
                t = time.perf_counter()
                case.run(backward)
                dt = time.perf_counter() - t
                if rnd > 0:
                    times[case.name].append(dt)
    return {name: 1e3 * statistics.median(t) for name, t in times.items()}


def build_both(ocnn, args: argparse.Namespace):
    points, normals = sample_points(os.path.join(args.mesh_dir, args.mesh), args.points)
    ours = build_octree((points, normals), args.depth, adaptive=False)
    xyz, nrm = ocnn_inputs(points, normals)
    ref = ocnn.octree.Octree(depth=args.depth, full_depth=2)
    ref.build_octree(ocnn.octree.Points(points=xyz, normals=nrm))
    ref.construct_all_neigh()
    return ours, ref


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    ocnn = import_ocnn()
    torch.manual_seed(0)
    default_threads = torch.get_num_threads()
    ours_tree, ref_tree = build_both(ocnn, args)
    d, c = args.depth, args.channels
    neighbors = torch.from_numpy(ours_tree.levels[d].neighbors.astype(np.int64))
    n = len(neighbors)
    if n != int(ref_tree.nnum[d]):
        raise SystemExit(f"node counts differ at depth {d}: ours {n}, ocnn {int(ref_tree.nnum[d])}")
    x0, grad = torch.randn(n, c), torch.randn(n, c)

    conv = OctreeConv(c, c)
    ref_convs = {m: ocnn.nn.OctreeConv(c, c, kernel_size=[3], stride=1, nempty=False, method=m)
                 for m in ("explicit_gemm", "block_gemm")}
    for rc in ref_convs.values():
        with torch.no_grad():
            rc.weights.copy_(conv.weight)
    with torch.no_grad():
        ours_out = conv(x0, neighbors)
        diff = max(float((ours_out - rc(x0, ref_tree, d)).abs().max()) for rc in ref_convs.values())

    cases = [
        autograd_case(OURS, lambda x: conv(x, neighbors), x0, grad, [conv.weight]),
        autograd_case(ONE, lambda x: octree_conv(x, neighbors, conv.weight, chunk_rows=n), x0, grad,
                      [conv.weight]),
        autograd_case(PER_OFFSET, lambda x: per_offset_conv(x, neighbors, conv.weight), x0, grad,
                      [conv.weight]),
        autograd_case(OCNN_EXPLICIT, lambda x: ref_convs["explicit_gemm"](x, ref_tree, d), x0, grad,
                      [ref_convs["explicit_gemm"].weights]),
        autograd_case(OCNN_BLOCK, lambda x: ref_convs["block_gemm"](x, ref_tree, d), x0, grad,
                      [ref_convs["block_gemm"].weights]),
        *bare_cases(n, c, grad),
    ]
    print(f"python {sys.version.split()[0]}, torch {torch.__version__}, ocnn {ocnn.__version__}; "
          f"cpus {os.cpu_count()}, torch default threads {default_threads}; load average "
          f"{os.getloadavg()[0]:.2f} (1 min)")
    print(f"{args.mesh}: {args.points} points, full octree depth {d}: N = {n} nodes at depth {d} "
          f"(ocnn: {int(ref_tree.nnum[d])}); conv {c} -> {c}, float32; gathered matrix "
          f"{n} x {27 * c} = {n * 27 * c * 4 / 2**20:.0f} MiB")
    print(f"max |ours - ocnn| forward, same weights: {diff:.2e}")

    results = {}
    for threads in (default_threads, 1):
        for backward in (True, False):
            results[(threads, backward)] = time_cases(cases, args.repeats, threads, backward)
    names = [cs.name for cs in cases]
    print(f"\nTime (ms, median of {args.repeats} after 1 warm-up, interleaved)")
    print(table(["case"] + [f"{'fwd+bwd' if b else 'fwd'} {t} thr" for t, b in results],
                [[nm] + [f"{r[nm]:.1f}" for r in results.values()] for nm in names]))

    ratios = []
    for threads in (default_threads, 1):
        r = results[(threads, True)]
        ocnn_best = min(r[OCNN_EXPLICIT], r[OCNN_BLOCK])
        ratios += [[f"{threads}", "ours / best ocnn", f"{r[OURS] / ocnn_best:.3f}", f"<= {TARGET_OCNN}",
                    "yes" if r[OURS] / ocnn_best <= TARGET_OCNN else "NO"],
                   [f"{threads}", "ours / bare GEMM (fresh)", f"{r[OURS] / r[BARE]:.3f}", f"<= {TARGET_BARE}",
                    "yes" if r[OURS] / r[BARE] <= TARGET_BARE else "NO"],
                   [f"{threads}", "ours / bare GEMM (out=)", f"{r[OURS] / r[BARE_OUT]:.3f}", f"<= {TARGET_BARE}",
                    "yes" if r[OURS] / r[BARE_OUT] <= TARGET_BARE else "NO"]]
    print("\nForward + backward ratios against the spec's targets")
    print(table(["threads", "ratio", "value", "target", "met"], ratios))
    print(f"load average after: {os.getloadavg()[0]:.2f} (1 min)")
    if args.json:
        with open(args.json, "w") as f:
            json.dump({"config": vars(args) | {"n": n, "torch_default_threads": default_threads},
                       "max_abs_diff_vs_ocnn": diff,
                       "ms": {f"{'fwd+bwd' if b else 'fwd'}_{t}thr": r for (t, b), r in results.items()}},
                      f, indent=2)
    return 0


if __name__ == "__main__":
    sys.exit(main())
