"""This checkout's octree build against another checkout's, in one process: time and equality.

Both builds get the same points (100k area-weighted samples of each mesh, face normals, seed 0)
and run interleaved (one warm-up, then the median of ``--repeats``), so the machine's drift
affects both alike.  With ``--equal``, every mesh in ``--mesh-dir`` is built at depths 6-8 by both
and the labels, planes and delta_O compared; ``--previous-closing-edge`` builds this checkout with the
boundary-probe rule before commit 22afaf2 (see ``bench.octree_label_changes``).

    git worktree add ../aocnn-e951434 e951434          # the build before the speed-up
    python -m bench.octree_versions --other ../aocnn-e951434 [--meshes ...] [--repeats 7]
    python -m bench.octree_versions --other ../aocnn-e951434 --equal --previous-closing-edge
"""

from __future__ import annotations

import contextlib
import os
import statistics
import sys
import time
import types

import numpy as np

from bench.octree_build import DEFAULT_MESH_DIR, mesh_files, sample_points
from model.cli import command_parser
from model.octree import build_octree


def load_other(path: str) -> types.ModuleType:
    """``model.octree`` of the checkout at ``path``, imported beside this one's."""
    ours = {k: sys.modules.pop(k) for k in list(sys.modules) if k == "model" or k.startswith("model.")}
    sys.path.insert(0, os.path.abspath(path))
    try:
        import model.octree as other
    finally:
        sys.path.pop(0)
        for k in [k for k in sys.modules if k == "model" or k.startswith("model.")]:
            del sys.modules[k]
        sys.modules.update(ours)
    return other


def timing(other: types.ModuleType, names: list[str], mesh_dir: str, depth: int, repeats: int) -> None:
    print(f"{'mesh':24s} {'mode':9s} {'other ms':>9s} {'this ms':>8s} {'speed-up':>9s}")
    for name in names:
        pts, nrm = sample_points(os.path.join(mesh_dir, name), 100_000)
        for adaptive in (False, True):
            times: dict[str, list[float]] = {"other": [], "this": []}
            for r in range(repeats + 1):
                for tag, build in (("other", other.build_octree), ("this", build_octree)):
                    t = time.perf_counter()
                    build((pts, nrm), depth, adaptive=adaptive)
                    if r:
                        times[tag].append(time.perf_counter() - t)
            o, n = (statistics.median(times[k]) * 1000 for k in ("other", "this"))
            print(f"{name:24s} {'adaptive' if adaptive else 'full':9s} {o:9.1f} {n:8.1f} {o / n:8.2f}x",
                  flush=True)


def equality(other: types.ModuleType, names: list[str], mesh_dir: str, previous_rule: bool) -> int:
    from bench.octree_label_changes import closing_edge_unprobed

    same_builds, same_planes, builds, worst = 0, 0, 0, 0.0
    for name in names:
        pts, nrm = sample_points(os.path.join(mesh_dir, name), 100_000)
        for depth in (6, 7, 8):
            with closing_edge_unprobed() if previous_rule else contextlib.nullcontext():
                a = build_octree((pts, nrm), depth, neighbors=False)
            b = other.build_octree((pts, nrm), depth, neighbors=False)
            same = a.nodes_per_depth() == b.nodes_per_depth() and all(
                np.array_equal(x.label, y.label) and np.array_equal(np.isfinite(x.error), np.isfinite(y.error))
                for x, y in zip(a.levels, b.levels))
            diff = max((float(np.abs(x.error[m].astype(float) - y.error[m]).max())
                        for x, y in zip(a.levels, b.levels)
                        for m in [np.isfinite(x.error) & np.isfinite(y.error)] if same and m.any()),
                       default=0.0)
            planes = same and all(np.array_equal(x.plane, y.plane) for x, y in zip(a.levels, b.levels))
            builds, same_builds, worst = builds + 1, same_builds + same, max(worst, diff)
            same_planes += planes
            print(f"{name:30s} depth {depth}: labels {'same' if same else 'DIFFER'}, planes "
                  f"{'same' if planes else 'differ'}, largest delta_O difference {diff:.1e}", flush=True)
    print(f"\n{same_builds}/{builds} builds with identical labels, {same_planes}/{builds} with identical planes; "
          f"largest delta_O difference {worst:.1e}")
    return 0 if same_builds == builds else 1


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.octree_versions", __doc__, [
        "python -m bench.octree_versions --other ../aocnn-e951434",
        "python -m bench.octree_versions --other ../aocnn-e951434 --equal"])
    ap.add_argument("--other", required=True, help="path of the other checkout (its repository root)")
    ap.add_argument("--meshes", nargs="*", default=None, help="file names in --mesh-dir (default: the bench's meshes)")
    ap.add_argument("--mesh-dir", default=DEFAULT_MESH_DIR,
                    help="folder of the meshes (default: ../shared/meshes beside the checkout)")
    ap.add_argument("--depth", type=int, default=8, help="octree depth of the timing (default 8)")
    ap.add_argument("--repeats", type=int, default=7, help="timed runs; the median is reported (default 7)")
    ap.add_argument("--equal", action="store_true", help="compare labels and delta_O instead of timing")
    ap.add_argument("--previous-closing-edge", action="store_true",
                    help="build this checkout with the boundary-probe rule before commit 22afaf2")
    args = ap.parse_args(argv)
    if not os.path.isdir(os.path.join(args.other, "model", "octree")):
        print(f"octree_versions: no model/octree under {args.other}", file=sys.stderr)
        return 2
    other = load_other(args.other)
    if args.equal:
        return equality(other, args.meshes or mesh_files(args.mesh_dir), args.mesh_dir,
                        args.previous_closing_edge)
    timing(other, args.meshes or ["stanford_bunny.obj", "abc3.stl", "homer.obj", "rocker_arm.obj"],
           args.mesh_dir, args.depth, args.repeats)
    return 0


if __name__ == "__main__":
    sys.exit(main())
