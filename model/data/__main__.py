"""Build a dataset (procedural shapes, a ModelNet40, ShapeNet or 3D-R2N2 layout on disk, or a
folder of one's own mesh files to evaluate on) as per-shape records with a manifest, in one
process or as shards; merge shard builds.

    python -m model.data build --out DIR --per-category N --depth D [--seed S] [--workers K]
                              [--categories chair table ...] [--views 24] [--partial 2]
    python -m model.data build --out DIR --source modelnet40|shapenet|r2n2|folder --root PATH
                              [--shapenet-root PATH] [--per-category N] [--up z] --depth D ...
    python -m model.data build ... --shard K/N        (part K of N, 0 <= K < N; one job each)
    python -m model.data merge --out DIR SHARD_DIR [SHARD_DIR ...]

A cluster builds one dataset as N independent jobs (a Kubernetes Indexed Job passes
``--shard $JOB_COMPLETION_INDEX/N``, a SLURM array ``--shard $SLURM_ARRAY_TASK_ID/N``), each
writing its records and ``manifest.shard-K-of-N.json``; ``merge`` checks the shards and writes
the manifest a single build would have written.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

from ..cli import command_parser
from ..octree.build import MAX_BUILD_DEPTH
from ..octree.geometry import AXES
from .compare import compare_datasets
from .dataset import SOURCES, BuildConfig, Shard, build_dataset, layout_tasks, merge_shards, procedural_tasks
from .shapes import CATEGORIES, GENERATORS


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = command_parser("python -m model.data", __doc__, [
        "python -m model.data build --out data/procedural --per-category 100 --depth 6 --workers 2",
        "python -m model.data build --out data/part --per-category 800 --depth 7 --shard 0/8",
        "python -m model.data build --out data/eval7 --per-category 800 --depth 7 --splits val test",
        "python -m model.data merge --out data/all data/part0 data/part1",
        "python -m model.data compare data/procedural other-machine/procedural"])
    sub = ap.add_subparsers(dest="command", required=True)
    b = sub.add_parser("build", help="build (or resume) a dataset of per-shape records and a manifest")
    b.add_argument("--out", required=True, help="dataset folder (created; a partial build there is resumed)")
    b.add_argument("--source", choices=SOURCES, default="procedural",
                   help="procedural shapes (default) or a real dataset layout under --root")
    b.add_argument("--root", help="dataset root for --source modelnet40, shapenet or r2n2; for --source folder, "
                   "a folder of mesh files (OBJ, OFF, STL, PLY, GLB, glTF), each a test shape")
    b.add_argument("--shapenet-root", help="ShapeNetCore.v2 root holding the meshes of --source r2n2")
    b.add_argument("--per-category", type=int, default=None,
                   help="shapes per category (required for procedural; a cap for real datasets)")
    b.add_argument("--categories", nargs="+", default=None, help="only these categories")
    b.add_argument("--depth", type=int, default=6, help="octree depth of the records (default 6)")
    b.add_argument("--seed", type=int, default=0, help="seed of shapes, renders and partial scans (default 0)")
    b.add_argument("--workers", type=int, default=max(1, (os.cpu_count() or 1)),
                   help="worker processes (default: all cores)")
    b.add_argument("--generator", type=int, choices=sorted(GENERATORS), default=1,
                   help="version of the procedural generators: " + "; ".join(f"{k}: {v}" for k, v in GENERATORS.items())
                        + " (default 1)")
    b.add_argument("--up", choices=AXES, default="y",
                   help="real meshes: their up axis, turned to y, the procedural shapes' and ShapeNet's (default "
                        "y: as read; ModelNet40's meshes are z-up)")
    b.add_argument("--views", type=int, default=24, help="renders per shape (default 24)")
    b.add_argument("--render-size", type=int, default=137, help="render side in pixels (default 137, 3D-R2N2's)")
    b.add_argument("--partial", type=int, default=2, help="partial scans per shape (default 2)")
    b.add_argument("--scan-resolution", type=int, default=160, help="rays per side of each scanner view (default 160)")
    b.add_argument("--shard", default=None, help="build only part K of N (K/N, 0 <= K < N) and write "
                   "manifest.shard-K-of-N.json; join the parts with merge (default: the whole dataset)")
    b.add_argument("--splits", nargs="+", choices=("train", "val", "test"), default=None,
                   help="build only the records of these splits (the same records a whole build makes; "
                        "e.g. --splits test to evaluate without building the training set); the "
                        "manifest still lists the other splits' records already built in --out")
    b.add_argument("--quiet", action="store_true", help="no progress bar")
    m = sub.add_parser("merge", help="join shard builds (--shard K/N) into one dataset and its manifest")
    m.add_argument("--out", required=True, help="dataset folder for the merged manifest (records are copied "
                   "there from shard folders elsewhere)")
    m.add_argument("shards", nargs="+", help="folders holding manifest.shard-K-of-N.json and their records")
    c = sub.add_parser("compare", help="compare two builds of one dataset record by record (same structure, "
                       "and how far floating values differ); exit status 1 when the structure differs")
    c.add_argument("first", help="a dataset folder")
    c.add_argument("second", help="another build of the same dataset")
    return ap.parse_args(argv)


def run(args: argparse.Namespace) -> dict:
    if args.command == "merge":
        return merge_shards(args.out, args.shards)
    if args.command == "compare":
        return {"comparison": compare_datasets(args.first, args.second)}
    shard = Shard.parse(args.shard) if args.shard else None
    if not 2 <= args.depth <= MAX_BUILD_DEPTH:
        raise ValueError(f"--depth must be in 2..{MAX_BUILD_DEPTH}, got {args.depth}")
    if args.per_category is not None and args.per_category < 1:
        raise ValueError(f"--per-category must be at least 1, got {args.per_category}")
    for name in ("workers", "views", "render_size", "scan_resolution"):
        if getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be at least 1")
    if args.partial < 0:
        raise ValueError("--partial must be 0 or more")
    cats = tuple(args.categories) if args.categories else None
    if args.source == "procedural":
        if args.up != "y":
            raise ValueError("--up applies to real meshes only: the procedural shapes are y-up")
        if args.per_category is None:
            raise ValueError("--per-category is required for procedural shapes")
        if cats:
            unknown = sorted(set(cats) - set(CATEGORIES))
            if unknown:
                raise ValueError(f"unknown categories {unknown}; valid: {', '.join(CATEGORIES)}")
        tasks = procedural_tasks(args.per_category, args.seed, cats or CATEGORIES)
    else:
        if args.generator != 1:
            raise ValueError("--generator applies to --source procedural only")
        if not args.root:
            raise ValueError(f"--root is required for --source {args.source}")
        tasks = layout_tasks(args.source, args.root, args.per_category, cats, args.shapenet_root)
        if not tasks:
            raise ValueError(f"no shapes found under {args.root} for --source {args.source}")
    keep = []
    if args.splits:
        keep = [t for t in tasks if t.split not in args.splits]     # listed again where already built
        tasks = [t for t in tasks if t.split in args.splits]
        if not tasks:
            raise ValueError(f"no shapes of splits {', '.join(args.splits)} among those asked for")
    cfg = BuildConfig(depth=args.depth, views=args.views, render_size=args.render_size,
                      partial_scans=args.partial, scan_resolution=args.scan_resolution, seed=args.seed,
                      generator=args.generator, up=args.up)
    return build_dataset(args.out, tasks, cfg, workers=args.workers, progress=not args.quiet, shard=shard,
                         keep=keep)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    t = time.perf_counter()
    try:
        manifest = run(args)
    except (ValueError, FileNotFoundError, NotADirectoryError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if "comparison" in manifest:
        c = manifest["comparison"]
        print(f"{c.compared} records compared: {c.same_bytes} byte-identical"
              + (f"; {len(c.missing)} in one build only" if c.missing else ""))
        for name, d in c.arrays.items():
            print(f"  {name}: differs in {d.records} records" + (f", max |difference| {d.max_abs:.3g}" if d.max_abs else "")
                  + (f", {d.shape_or_integer} in shape or integer values" if d.shape_or_integer else ""))
        print("same structure (shapes and integer arrays)" if c.same_structure else "the structure differs")
        return 0 if c.same_structure else 1
    n = len(manifest["records"])
    minutes = (time.perf_counter() - t) / 60
    print(f"{args.out}: {n} records ({manifest['splits']}), {minutes:.1f} min")
    return 0


if __name__ == "__main__":
    sys.exit(main())
