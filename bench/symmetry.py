"""The mirror-plane search of a partial scan (``model.octree.symmetry.find_mirror``, run by the
completion request with ``symmetry=true``): its time against the reference search that measures
every candidate plane exactly, and whether the two agree.

Inputs: ``--scan`` (a point cloud file, default the example car scan, 20,000 points) and, with
``--data``, every partial scan of ``--split`` of that dataset.  Each scan is searched both ways in
the same run, one after the other; times are medians over ``--repeats`` runs per scan.  Agreement:
how many scans get the other decision (mirrored or not at the service's support threshold), and
the largest differences of plane offset (in the scan's units) and of support.

    python -m bench.symmetry [--scan examples/car_partial_scan.ply] [--data data/procedural --split val]
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from bench.surface import timed
from model.cli import command_parser

REPO = Path(__file__).resolve().parents[1]


@dataclass
class Comparison:
    """One scan searched both ways: median seconds and the planes found."""

    name: str
    points: int
    fast: float
    reference: float
    fast_mirror: object
    reference_mirror: object


def compare(name: str, points: np.ndarray, repeats: int) -> Comparison:
    from model.octree.symmetry import find_mirror

    fast, _, fm = timed(lambda: find_mirror(points), repeats)
    ref, _, rm = timed(lambda: find_mirror(points, shortlist=None), repeats)
    return Comparison(name, len(points), fast, ref, fm, rm)


def dataset_scans(data: str, split: str):
    """(name, points) of every partial scan of ``split`` in the dataset ``data``."""
    from model.data.dataset import load_record
    from model.train.data import manifest_rows

    _, rows = manifest_rows(Path(data), split)
    for row in rows:
        rec = load_record(Path(data) / row["path"])
        for j in range(len(rec["partial_offsets"]) - 1):
            yield f"{row['shape_id']} scan {j}", rec.partial(j)[0]


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.symmetry", __doc__, [
        "python -m bench.symmetry",
        "python -m bench.symmetry --data data/procedural --split val --repeats 1"])
    ap.add_argument("--scan", default=str(REPO / "examples" / "car_partial_scan.ply"),
                    help="a partial scan (PLY/OBJ/XYZ...) timed on its own (default the example car scan)")
    ap.add_argument("--data", default=None, help="also every partial scan of a dataset's split (default: none)")
    ap.add_argument("--split", default="val", help="the dataset's split (default val)")
    ap.add_argument("--repeats", type=int, default=7, help="timed runs per scan and search after a warm-up (default 7)")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    import trimesh

    from model.octree.symmetry import MIN_SUPPORT

    scan = np.asarray(trimesh.load(args.scan).vertices, dtype=np.float64)
    rows = [compare(Path(args.scan).name, scan, args.repeats)]
    one = rows[0]
    print(f"{one.name} ({one.points} points): {one.fast * 1e3:.1f} ms against {one.reference * 1e3:.1f} ms "
          f"for the reference search ({one.reference / one.fast:.2f}x faster); planes x = {one.fast_mirror.offset:.5f} "
          f"/ {one.reference_mirror.offset:.5f}, support {one.fast_mirror.support:.3f} / {one.reference_mirror.support:.3f}")
    if args.data:
        rows = [compare(name, pts, args.repeats) for name, pts in dataset_scans(args.data, args.split)]
        fast = np.array([r.fast for r in rows])
        ref = np.array([r.reference for r in rows])
        offsets = np.array([abs(r.fast_mirror.offset - r.reference_mirror.offset) for r in rows])
        supports = np.array([r.fast_mirror.support - r.reference_mirror.support for r in rows])
        flips = [r.name for r in rows if r.fast_mirror.supported() != r.reference_mirror.supported()]
        print(f"{args.data} {args.split}: {len(rows)} scans, median {np.median([r.points for r in rows]):.0f} points; "
              f"median {np.median(fast) * 1e3:.1f} ms against {np.median(ref) * 1e3:.1f} ms "
              f"(ratio of medians {np.median(ref) / np.median(fast):.2f}x, of totals {ref.sum() / fast.sum():.2f}x)")
        print(f"  other decision at support >= {MIN_SUPPORT}: {len(flips)} of {len(rows)} {flips if flips else ''}".rstrip())
        print(f"  plane offset difference: median {np.median(offsets):.1e}, largest {offsets.max():.4f}, "
              f"above 0.001 on {(offsets > 1e-3).sum()}; support difference from {supports.min():+.3f} to {supports.max():+.3f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
