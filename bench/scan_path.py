"""A completion's work outside the HTTP layer, step by step, in one process: where a scan's
request spends its time, and each fast step against the reference it replaced, in the same run.

    python -m bench.scan_path [--scan examples/car_partial_scan.ply] [--repeats 10]
                              [--bundle models/bundles/completion] [--json PATH]

Steps (the service's order and settings): the scan read and validated (its normals
estimated), of which the k nearest neighbours alone; the symmetry search; the scan's octree
(adaptive, neighbour tables); encoder; decoder (with the bundle's keep_scan bias); keep_scan; the
patch mesh.  Then the same two first steps as the service runs them: the scan's layout (its
mirror plane and its points placed in the scan frame, :func:`lay_out_scan`) found on the second
core while the normals are oriented on the first, and the octree built from that layout.
References timed alongside, run by run: the neighbours from SciPy's cKDTree (what the grid
search returns, bit for bit), and the octree with every probe asked of a k-d tree
(``probe_search=False``: the same octree).  Prints the median and the
worst of ``--repeats`` runs after one warm-up, and the octree target of the request-speed issue
(the build at depth 7 on a 20,000-point scan <= 20 ms).
"""

from __future__ import annotations

import json
import statistics
import sys
import time
from pathlib import Path

from scipy.spatial import cKDTree

from export.bundle import load_bundle
from export.runtime import Runtime
from model.cli import command_parser
from model.octree.batch import merge_octrees, split_octree
from model.octree.build import build_octree
from model.octree.fuse import keep_scan
from model.octree.knn import nearest
from model.octree.pointcloud import scan_frame
from model.octree.scan import lay_out_scan, scan_octree
from model.octree.symmetry import symmetrize
from model.surface import surface_mesh
from service.inputs import shape_input

BUILD_TARGET_MS = 20.0
SERVED_READ = "read + normals, layout beside (served)"
SERVED_OCTREE = "octree from the layout (served)"


def run_once(data: bytes, name: str, rt: Runtime, o) -> dict[str, float]:
    """Seconds per step of one completion of the scan ``data``."""
    times: dict[str, float] = {}

    def timed(step: str, fn):
        t = time.perf_counter()
        out = fn()
        times[step] = time.perf_counter() - t
        return out

    loaded = timed("read + normals", lambda: shape_input(data, name, o.depth, 2_000_000, 500_000_000))
    pts = loaded.cloud.points
    timed("neighbours (grid)", lambda: nearest(pts, 16))
    timed("neighbours (cKDTree, reference)", lambda: cKDTree(pts).query(pts, k=16, workers=-1))
    cloud, _ = timed("symmetry", lambda: symmetrize(loaded.cloud))
    settings = dict(adaptive=o.adaptive, full_depth=o.full_depth, adaptive_depth=o.adaptive_depth,
                    **({"threshold": o.threshold} if o.threshold else {}))
    scan = timed("octree", lambda: scan_octree(cloud, o.depth, **settings))
    timed("octree (k-d tree probes, reference)", lambda: _reference_octree(cloud, o.depth, settings))
    latent, guide = timed("encoder", lambda: rt.encode_scan(merge_octrees([scan])))
    # decoded as the service decodes a scan whose own patches it keeps
    tree = timed("decoder", lambda: split_octree(rt.decode(latent, None, rt.bundle.keep_scan_bias, guide),
                                                 neighbors=False)[0])
    tree.normalizations = list(scan.normalizations)
    fused = timed("keep_scan", lambda: keep_scan(tree, scan))
    timed("patch mesh", lambda: surface_mesh(fused, "patches"))
    found = {}

    def lay_out(points):
        found["layout"] = lay_out_scan(points, o.depth, adaptive=o.adaptive)

    served = timed(SERVED_READ, lambda: shape_input(data, name, o.depth, 2_000_000, 500_000_000, beside=lay_out))
    cloud, _ = symmetrize(served.cloud, mirror=found["layout"].mirror)
    timed(SERVED_OCTREE, lambda: scan_octree(cloud, o.depth, placement=found["layout"].placement, **settings))
    return times


def _reference_octree(cloud, depth: int, settings: dict):
    """:func:`scan_octree` with every patch->surface probe asked of a k-d tree (the same octree)."""
    return build_octree(cloud, depth, normalization=scan_frame(cloud.points), probe_search=False, **settings)


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.scan_path", __doc__, ["python -m bench.scan_path --repeats 10"])
    ap.add_argument("--scan", default="examples/car_partial_scan.ply", help="the scan (default the example)")
    ap.add_argument("--bundle", default="models/bundles/completion", help="the completion bundle")
    ap.add_argument("--repeats", type=int, default=10, help="runs measured after one warm-up (default 10)")
    ap.add_argument("--json", default=None, help="also write the figures here")
    args = ap.parse_args(argv)
    bundle = load_bundle(args.bundle)
    rt, o = Runtime(bundle, spinning=False), bundle.octree      # as the service runs it
    data = Path(args.scan).read_bytes()
    run_once(data, Path(args.scan).name, rt, o)
    runs = [run_once(data, Path(args.scan).name, rt, o) for _ in range(args.repeats)]
    n_points = len(shape_input(data, Path(args.scan).name, o.depth, 2_000_000, 500_000_000).cloud)
    rows = {step: (1e3 * statistics.median(r[step] for r in runs), 1e3 * max(r[step] for r in runs))
            for step in runs[0]}
    print(f"{args.scan}: {n_points:,} points, depth {o.depth}, {args.repeats} runs (median / worst ms)")
    for step, (med, worst) in rows.items():
        print(f"  {step:38s} {med:7.1f} {worst:7.1f}")
    grid, ref = rows["neighbours (grid)"][0], rows["neighbours (cKDTree, reference)"][0]
    octree, octree_ref = rows["octree"][0], rows["octree (k-d tree probes, reference)"][0]
    print(f"neighbours: {grid / ref:.2f}x the cKDTree's time; octree: {octree / octree_ref:.2f}x the k-d tree "
          f"probes' time")
    met = "met" if rows["octree"][1] <= BUILD_TARGET_MS else "missed"
    print(f"target: the octree <= {BUILD_TARGET_MS:.0f} ms (worst run): {rows['octree'][1]:.1f} ms, {met}")
    print(f"the octree from the layout found beside the normals, as served: {rows[SERVED_OCTREE][1]:.1f} ms (worst run)")
    steps = [s for s in rows if "reference" not in s and s != "neighbours (grid)" and "served" not in s]
    served = [s for s in steps if s not in ("read + normals", "symmetry", "octree")] + [SERVED_READ, SERVED_OCTREE]
    print(f"total of the steps (medians): {sum(rows[s][0] for s in steps):.1f} ms one after another, "
          f"{sum(rows[s][0] for s in served):.1f} ms as served")
    if args.json:
        Path(args.json).write_text(json.dumps({"points": n_points, "median_ms": {k: v[0] for k, v in rows.items()},
                                               "worst_ms": {k: v[1] for k, v in rows.items()}}, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
