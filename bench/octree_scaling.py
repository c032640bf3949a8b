"""How the octree build scales with depth and with points: time and peak memory.

For each mesh, points count (``--points``, default 100k and 1M; area-weighted samples with face
normals, seed 0) and depth (``--depths``, default 6-10), each build runs in a fresh process so
that its peak resident memory is its own: ours full (O-CNN octree + neighbour tables), ours
adaptive (+ neighbour tables) and, where it fits in ``--ocnn-max-gb``, ocnn's full build +
``construct_all_neigh`` at 1 thread.  Time is the median of ``--repeats`` builds after one
warm-up; memory is the process's peak RSS minus its RSS after loading the points.

    python -m bench.octree_scaling [--depths 6 7 8 9 10] [--points 100000 1000000]
                                   [--meshes stanford_bunny.obj] [--mesh-dir DIR] [--repeats 3]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import statistics
import subprocess
import sys
import time

from model.cli import command_parser

CASES = ("ours full", "ours adaptive", "ocnn full")


def _rss_mb() -> float:
    with open("/proc/self/statm") as fh:
        return int(fh.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


def measure(case: str, mesh: str, points: int, depth: int, repeats: int) -> dict:
    """In a child process: median build time and the peak memory above the loaded points."""
    import torch

    from bench.octree_build import import_ocnn, ocnn_case, ocnn_inputs, ours_case, sample_points

    torch.set_num_threads(1)
    pts, nrm = sample_points(mesh, points)
    if case == "ocnn full":
        build = ocnn_case(case, import_ocnn(), *ocnn_inputs(pts, nrm), depth, True, 1)
    else:
        build = ours_case(case, pts, nrm, depth, case == "ours adaptive", [], 1)
    base = _rss_mb()
    times = []
    for _ in range(repeats + 1):
        t = time.perf_counter()
        tree = build.run()
        times.append(time.perf_counter() - t)
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
    nodes = int(tree.nnum.sum()) if case == "ocnn full" else int(sum(tree.nodes_per_depth()))
    return {"case": case, "points": points, "depth": depth, "nodes": nodes,
            "seconds": statistics.median(times[1:]), "memory_mb": peak - base}


def main(argv: list[str] | None = None) -> int:
    from bench.octree_build import DEFAULT_MESH_DIR

    ap = command_parser("python -m bench.octree_scaling", __doc__, [
        "python -m bench.octree_scaling --depths 6 7 8 --points 100000"])
    ap.add_argument("--depths", type=int, nargs="+", default=[6, 7, 8, 9, 10], help="octree depths (default 6-10)")
    ap.add_argument("--points", type=int, nargs="+", default=[100_000, 1_000_000],
                    help="sampled points per mesh (default 100000 1000000)")
    ap.add_argument("--meshes", nargs="+", default=["stanford_bunny.obj"],
                    help="mesh files in --mesh-dir, or paths (default stanford_bunny.obj)")
    ap.add_argument("--mesh-dir", default=DEFAULT_MESH_DIR, help=f"folder of the meshes (default {DEFAULT_MESH_DIR})")
    ap.add_argument("--repeats", type=int, default=3, help="timed builds after a warm-up, median taken (default 3)")
    ap.add_argument("--ocnn-max-depth", type=int, default=10, help="skip ocnn above this depth (default 10)")
    ap.add_argument("--json", default=None, help="also write the rows here (default: none)")
    ap.add_argument("--child", nargs=4, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.child:
        case, mesh, points, depth = args.child
        print(json.dumps(measure(case, mesh, int(points), int(depth), args.repeats)))
        return 0
    rows = []
    print(f"{'mesh':>20} {'points':>9} {'depth':>5} {'case':>14} {'nodes':>11} {'seconds':>9} {'memory MB':>10}")
    for name in args.meshes:
        mesh = name if os.path.isfile(name) else os.path.join(args.mesh_dir, name)
        for points in args.points:
            for depth in args.depths:
                for case in CASES:
                    if case == "ocnn full" and depth > args.ocnn_max_depth:
                        continue
                    cmd = [sys.executable, "-m", "bench.octree_scaling", "--repeats", str(args.repeats),
                           "--child", case, mesh, str(points), str(depth)]
                    done = subprocess.run(cmd, capture_output=True, text=True)
                    if done.returncode:
                        print(f"{name:>20} {points:>9} {depth:>5} {case:>14} failed: "
                              f"{(done.stderr.strip().splitlines() or ['?'])[-1]}", flush=True)
                        continue
                    r = json.loads(done.stdout.strip().splitlines()[-1])
                    rows.append({"mesh": name, **r})
                    print(f"{name:>20} {points:>9} {depth:>5} {case:>14} {r['nodes']:>11,} {r['seconds']:>9.3f} "
                          f"{r['memory_mb']:>10.0f}", flush=True)
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(rows, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
