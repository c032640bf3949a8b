"""Octree build speed: ours (``model.octree.build_octree``) against the reference ``ocnn`` package.

For each mesh, ``--points`` (default 100k) oriented points are sampled (area-weighted, face
normals, seed 0) and, at each depth, the following are timed in the same process, interleaved run
by run (one warm-up, then the median of ``--repeats`` runs, ``time.perf_counter``):

* ours full      -- ``build_octree((points, normals), D, adaptive=False)`` (O-CNN octree + neighbours)
* ours adaptive  -- ``build_octree((points, normals), D, adaptive=True)``  (adaptive + neighbours)
  (ours runs on one thread: NumPy and single-worker SciPy k-d trees)
* ocnn full      -- ``Points`` + ``Octree(depth=D, full_depth=2)`` + ``build_octree`` +
  ``construct_all_neigh``, with torch at its default thread count and at 1 thread
* ocnn build     -- the same without ``construct_all_neigh`` (default threads)

Both libraries see the same points in the same cube: ocnn gets ours' unit-cube coordinates mapped
to ``[-1, 1]`` (float32 tensors prepared outside the timed region).  The script prints times,
ratios, node counts per depth (with a structural check of ours-full against ocnn: node and
non-empty counts per depth must match), the per-stage breakdown of our adaptive build and the
spec's depth-8 targets.

Run from the repository root::

    python -m bench.octree_build [--depths 6 7 8] [--repeats 7] [--points 100000]
                                 [--meshes stanford_bunny.obj abc3.stl] [--mesh-dir DIR]
                                 [--json PATH]
"""

from __future__ import annotations

import argparse
import importlib.machinery
import importlib.util
import json
import os
import statistics
import sys
import tempfile
import time
import types
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Any, Callable, Iterator

import numpy as np
import torch
import trimesh

from model.cli import command_parser
from model.octree import Normalization, build_octree
from model.octree.pointcloud import normalization_of

REPO_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DEFAULT_MESH_DIR = os.path.join(REPO_ROOT, "..", "shared", "meshes")
DEFAULT_MESHES = ["stanford_bunny.obj", "abc3.stl"]
FULL_DEPTH = 2
TARGET_DEPTH = 8
TARGET_RATIOS = {"full": 0.3, "adaptive": 0.35}
"""Issue 13: at depth 8, ours full <= 0.3x and ours adaptive <= 0.35x ocnn's full build + tables."""

OURS_FULL, OURS_ADAPTIVE = "ours full", "ours adaptive"
OCNN_DEFAULT, OCNN_ONE, OCNN_BUILD = "ocnn b+n default thr", "ocnn b+n 1 thr", "ocnn build only"


@dataclass
class Case:
    """One timed configuration: a callable building an octree, and torch's thread count for it."""

    name: str
    run: Callable[[], Any]
    threads: int


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    p = command_parser("python -m bench.octree_build", __doc__, [
        "python -m bench.octree_build --depths 6 7 8 --repeats 9"])
    p.add_argument("--depths", type=int, nargs="+", default=[6, 7, 8], help="octree depths (default 6 7 8)")
    p.add_argument("--repeats", type=int, default=7, help="timed runs; the median is reported (default 7)")
    p.add_argument("--points", type=int, default=100_000, help="points sampled per mesh (default 100000)")
    p.add_argument("--meshes", nargs="+", default=DEFAULT_MESHES,
                   help="mesh file names inside --mesh-dir, or paths (default: " + " ".join(DEFAULT_MESHES) + ")")
    p.add_argument("--mesh-dir", default=DEFAULT_MESH_DIR,
                    help="folder of the meshes (default: ../shared/meshes beside the checkout)")
    p.add_argument("--json", metavar="PATH", help="also write a JSON summary here")
    return p.parse_args(argv)


def import_ocnn() -> types.ModuleType:
    """Import ocnn, installing a ``torchvision`` stand-in first if torchvision is missing.

    ``import ocnn`` imports ``ocnn.models``, whose ``image2shape.py`` does
    ``from torchvision.models import resnet18`` at module load; torchvision cannot be installed
    here.  That is the only torchvision use in ocnn 2.3.3 and the image model is not used by this
    benchmark, so a stand-in whose ``resnet18`` raises is enough.  Module specs are set so that
    ``importlib.util.find_spec("torchvision")`` elsewhere does not fail on the stand-in.
    """
    if "torchvision" not in sys.modules and importlib.util.find_spec("torchvision") is None:
        def resnet18(*args: Any, **kwargs: Any) -> None:
            raise ImportError("torchvision stand-in (bench.octree_build): resnet18 is unavailable")

        tv = types.ModuleType("torchvision")
        tv.__spec__ = importlib.machinery.ModuleSpec("torchvision", None)
        models = types.ModuleType("torchvision.models")
        models.__spec__ = importlib.machinery.ModuleSpec("torchvision.models", None)
        models.resnet18 = resnet18
        tv.models = models
        sys.modules["torchvision"] = tv
        sys.modules["torchvision.models"] = models
    import ocnn
    return ocnn


def sample_points(path: str, n: int) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted surface samples of a mesh file and the normals of the faces they lie on."""
    return mesh_samples(trimesh.load(path, force="mesh"), n)


def mesh_samples(mesh: trimesh.Trimesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Area-weighted surface samples of ``mesh`` and the normals of the faces they lie on."""
    points, face = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points, dtype=np.float64), np.asarray(mesh.face_normals[face], dtype=np.float64)


def mesh_files(mesh_dir: str) -> list[str]:
    """The mesh file names in ``mesh_dir``, sorted."""
    return sorted(f for f in os.listdir(mesh_dir) if f.endswith((".obj", ".off", ".stl", ".ply")))


SNAP = 2.0 ** -21
"""Cube coordinates are snapped to this grid for ocnn: then x in [-1, 1], x + 1 and its product
with 2^(d-1) are exact in float32, so ocnn's float32 key arithmetic and our float64 arithmetic
put every point in the same octant.  (Unsnapped, ocnn's float32 rounding moves points that lie
within ~1e-7 of an octant boundary across it: 1-3 non-empty octants per depth at depths 7-8 on
most meshes of ../shared/meshes; ours is exact for the coordinates it is given.)  The shift is at
most 2^-22 of the cube, far below any octant."""
UNIT_CUBE = Normalization(center=np.full(3, 0.5), scale=1.0)


def snapped_cube(points: np.ndarray) -> np.ndarray:
    """Ours' unit-cube coordinates of ``points``, snapped to the :data:`SNAP` grid."""
    return np.round(normalization_of(points).to_cube(points) / SNAP) * SNAP


def ocnn_inputs(points: np.ndarray, normals: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """Float32 tensors for ocnn: the snapped unit-cube coordinates mapped to [-1, 1] (exact)."""
    return torch.from_numpy((snapped_cube(points) - 0.5) * 2.0).float(), torch.from_numpy(normals).float()


@contextmanager
def torch_threads(n: int) -> Iterator[None]:
    old = torch.get_num_threads()
    torch.set_num_threads(n)
    try:
        yield
    finally:
        torch.set_num_threads(old)


def ours_case(name: str, points: np.ndarray, normals: np.ndarray, depth: int, adaptive: bool,
              stage_log: list[dict[str, float]], threads: int) -> Case:
    def run() -> Any:
        timings: dict[str, float] = {}
        octree = build_octree((points, normals), depth, adaptive=adaptive, timings=timings)
        stage_log.append(timings)
        return octree
    return Case(name, run, threads)


def ocnn_case(name: str, ocnn: types.ModuleType, xyz: torch.Tensor, nrm: torch.Tensor,
              depth: int, neighbors: bool, threads: int) -> Case:
    def run() -> Any:
        octree = ocnn.octree.Octree(depth=depth, full_depth=FULL_DEPTH)
        octree.build_octree(ocnn.octree.Points(points=xyz, normals=nrm))
        if neighbors:
            octree.construct_all_neigh()
        return octree
    return Case(name, run, threads)


def time_cases(cases: list[Case], repeats: int) -> tuple[dict[str, list[float]], dict[str, Any]]:
    """One warm-up per case, then ``repeats`` rounds running every case once (interleaved)."""
    times: dict[str, list[float]] = {c.name: [] for c in cases}
    last: dict[str, Any] = {}
    for rnd in range(repeats + 1):
        for case in cases:
            with torch_threads(case.threads):
                t = time.perf_counter()
                last[case.name] = case.run()
                dt = time.perf_counter() - t
            if rnd > 0:
                times[case.name].append(dt)
    return times, last


def stage_medians(stage_log: list[dict[str, float]], totals: list[float]) -> dict[str, float]:
    """Median seconds per stage over the timed runs, plus the time spent outside any stage."""
    names = list(dict.fromkeys(k for run in stage_log for k in run))
    out = {k: statistics.median(run.get(k, 0.0) for run in stage_log) for k in names}
    out["(outside stages)"] = statistics.median(
        total - sum(run.values()) for run, total in zip(stage_log, totals))
    return out


def structure_check(ours_full: Any, ref: Any) -> list[dict[str, Any]]:
    """Per-depth node / non-empty counts of ours-full and ocnn, with mismatches flagged.

    ocnn reports every node of the full layers (depth < full_depth) as non-empty, so non-empty
    counts are compared from ``full_depth`` on; total node counts are compared at every depth.
    """
    rows = []
    nnum, nempty = ref.nnum.tolist(), ref.nnum_nempty.tolist()
    for d, (n, ne) in enumerate(zip(ours_full.nodes_per_depth(), ours_full.nonempty_per_depth())):
        problems = []
        if n != nnum[d]:
            problems.append("nodes")
        if d >= FULL_DEPTH and ne != nempty[d]:
            problems.append("non-empty")
        rows.append({"depth": d, "ours_nodes": n, "ocnn_nodes": nnum[d], "ours_nonempty": ne,
                     "ocnn_nonempty": nempty[d], "mismatch": problems})
    return rows


def bench_depth(ocnn: types.ModuleType, points: np.ndarray, normals: np.ndarray, xyz: torch.Tensor,
                nrm: torch.Tensor, depth: int, repeats: int, default_threads: int) -> dict[str, Any]:
    stage_log: list[dict[str, float]] = []
    cases = [
        ours_case(OURS_FULL, points, normals, depth, False, [], default_threads),
        ours_case(OURS_ADAPTIVE, points, normals, depth, True, stage_log, default_threads),
        ocnn_case(OCNN_DEFAULT, ocnn, xyz, nrm, depth, True, default_threads),
        ocnn_case(OCNN_ONE, ocnn, xyz, nrm, depth, True, 1),
        ocnn_case(OCNN_BUILD, ocnn, xyz, nrm, depth, False, default_threads),
    ]
    times, last = time_cases(cases, repeats)
    ms = {name: 1e3 * statistics.median(t) for name, t in times.items()}
    full, adaptive, ref = last[OURS_FULL], last[OURS_ADAPTIVE], last[OCNN_DEFAULT]
    return {
        "depth": depth,
        "ms": ms,
        "ratios": {
            "full/ocnn_default": ms[OURS_FULL] / ms[OCNN_DEFAULT],
            "full/ocnn_1thread": ms[OURS_FULL] / ms[OCNN_ONE],
            "adaptive/ocnn_default": ms[OURS_ADAPTIVE] / ms[OCNN_DEFAULT],
            "adaptive/ocnn_1thread": ms[OURS_ADAPTIVE] / ms[OCNN_ONE],
        },
        "total_nodes": {"ours_full": sum(full.nodes_per_depth()),
                        "ours_adaptive": sum(adaptive.nodes_per_depth()),
                        "ocnn": int(ref.nnum.sum())},
        "adaptive_per_depth": {"nodes": adaptive.nodes_per_depth(),
                               "nonempty": adaptive.nonempty_per_depth(),
                               "leaves": adaptive.leaves_per_depth()},
        # exact: ours built from the very coordinates ocnn got (untimed), not from the raw points
        "structure": structure_check(build_octree((snapped_cube(points), normals), depth, adaptive=False,
                                                  neighbors=False, normalization=UNIT_CUBE), ref),
        "adaptive_stages_ms": {k: 1e3 * v for k, v in
                               stage_medians(stage_log[1:], times[OURS_ADAPTIVE]).items()},
    }


def table(headers: list[str], rows: list[list[Any]]) -> str:
    cells = [headers] + [[str(c) for c in row] for row in rows]
    widths = [max(len(row[i]) for row in cells) for i in range(len(headers))]
    lines = ["  ".join(c.rjust(w) for c, w in zip(row, widths)) for row in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    return "\n".join(lines)


def print_mesh(name: str, n_points: int, results: list[dict[str, Any]], repeats: int,
               default_threads: int) -> None:
    print(f"\n=== {name}: {n_points} points ===")
    print(f"\nTime (ms, median of {repeats}); b+n = build + neighbour tables; "
          f"default torch threads = {default_threads}")
    print(table(["depth", OURS_FULL, OURS_ADAPTIVE, OCNN_DEFAULT, OCNN_ONE, OCNN_BUILD,
                 "full/ocnn(def)", "full/ocnn(1)", "adapt/ocnn(def)", "adapt/ocnn(1)"],
                [[r["depth"]] + [f"{r['ms'][k]:.1f}" for k in
                                 (OURS_FULL, OURS_ADAPTIVE, OCNN_DEFAULT, OCNN_ONE, OCNN_BUILD)]
                 + [f"{v:.3f}" for v in r["ratios"].values()] for r in results]))
    print("\nTotal nodes")
    print(table(["depth", "ours full", "ours adaptive", "ocnn", "adaptive/full"],
                [[r["depth"], *r["total_nodes"].values(),
                  f"{r['total_nodes']['ours_adaptive'] / r['total_nodes']['ours_full']:.3f}"]
                 for r in results]))
    for r in results:
        print(f"\nNodes per depth, max depth {r['depth']} (full: ours vs ocnn; non-empty "
              f"compared from depth {FULL_DEPTH}, ocnn counts full layers as non-empty)")
        ad = r["adaptive_per_depth"]
        print(table(["d", "full nodes", "ocnn nodes", "full non-empty", "ocnn non-empty",
                     "adaptive nodes", "adaptive non-empty", "adaptive leaves", "check"],
                    [[s["depth"], s["ours_nodes"], s["ocnn_nodes"], s["ours_nonempty"],
                      s["ocnn_nonempty"], ad["nodes"][d], ad["nonempty"][d], ad["leaves"][d],
                      "MISMATCH " + "+".join(s["mismatch"]) if s["mismatch"] else "ok"]
                     for d, s in enumerate(r["structure"])]))
    stages = list(dict.fromkeys(k for r in results for k in r["adaptive_stages_ms"]))
    print("\nOurs adaptive, per-stage time (ms, median per stage)")
    print(table(["stage"] + [f"depth {r['depth']}" for r in results],
                [[s] + [f"{r['adaptive_stages_ms'].get(s, 0.0):.1f}" for r in results]
                 for s in stages]
                + [["total (median)"] + [f"{r['ms'][OURS_ADAPTIVE]:.1f}" for r in results]]))


def evaluate_targets(summary: dict[str, list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """The spec's depth-8 targets, per mesh and per ocnn thread setting."""
    out = []
    for mesh, results in summary.items():
        for r in results:
            if r["depth"] != TARGET_DEPTH:
                continue
            for key, limit in TARGET_RATIOS.items():
                for threads in ("default", "1thread"):
                    ratio = r["ratios"][f"{key}/ocnn_{threads}"]
                    out.append({"mesh": mesh, "target": f"ours {key} <= {limit} x ocnn full",
                                "ocnn_threads": threads, "ratio": ratio, "met": ratio <= limit})
    return out


def print_targets(targets: list[dict[str, Any]]) -> None:
    print(f"\n=== Spec targets at depth {TARGET_DEPTH} ===")
    if not targets:
        print(f"not evaluated: depth {TARGET_DEPTH} was not measured")
        return
    print(table(["mesh", "target", "ocnn threads", "ratio", "met"],
                [[t["mesh"], t["target"], t["ocnn_threads"], f"{t['ratio']:.3f}",
                  "yes" if t["met"] else "NO"] for t in targets]))


def write_json(path: str, data: dict[str, Any]) -> None:
    directory = os.path.dirname(os.path.abspath(path))
    fd, tmp = tempfile.mkstemp(dir=directory, prefix=".octree_build.", suffix=".json")
    try:
        with os.fdopen(fd, "w") as f:
            json.dump(data, f, indent=2)
        os.replace(tmp, path)
    except BaseException:
        os.unlink(tmp)
        raise


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    ocnn = import_ocnn()
    default_threads = torch.get_num_threads()
    print(f"python {sys.version.split()[0]}, numpy {np.__version__}, torch {torch.__version__}, "
          f"ocnn {ocnn.__version__}; cpus {os.cpu_count()}, torch default threads "
          f"{default_threads}; depths {args.depths}, repeats {args.repeats}, points {args.points}")
    load_before = os.getloadavg()
    print(f"load average before: {load_before[0]:.2f} (1 min)")
    summary: dict[str, list[dict[str, Any]]] = {}
    for mesh in args.meshes:
        points, normals = sample_points(os.path.join(args.mesh_dir, mesh), args.points)
        xyz, nrm = ocnn_inputs(points, normals)
        summary[mesh] = [bench_depth(ocnn, points, normals, xyz, nrm, d, args.repeats,
                                     default_threads) for d in args.depths]
        print_mesh(mesh, len(points), summary[mesh], args.repeats, default_threads)
    targets = evaluate_targets(summary)
    print_targets(targets)
    mismatches = [(m, r["depth"], s["depth"]) for m, rs in summary.items() for r in rs
                  for s in r["structure"] if s["mismatch"]]
    load_after = os.getloadavg()
    print(f"\nload average after: {load_after[0]:.2f} (1 min); another process using a core slows "
          "multi-threaded torch most")
    print("Structure check ours-full vs ocnn: "
          + (f"{len(mismatches)} mismatched (mesh, max depth, depth): {mismatches}"
             if mismatches else "all node and non-empty counts match"))
    if args.json:
        write_json(args.json, {
            "config": {"depths": args.depths, "repeats": args.repeats, "points": args.points,
                       "meshes": args.meshes, "torch_default_threads": default_threads,
                       "torch": torch.__version__, "ocnn": ocnn.__version__,
                       "loadavg_1min_before_after": [load_before[0], load_after[0]]},
            "results": summary, "targets": targets})
    return 0


if __name__ == "__main__":
    sys.exit(main())
