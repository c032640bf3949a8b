"""Command line: build the octree of a mesh or point cloud and write its surface, closed or as
the leaf patches (and stats).

    python -m model.octree INPUT --depth D [--full] [--threshold VOXELS] [--points N]
                           [--surface watertight|patches] --out OUT.{ply,glb,obj,stl,off}
                           [--stats STATS.json] [--color-by-depth]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np
import trimesh

from ..cli import command_parser
from ..files import json_text, write_atomic
from ..surface import DEFAULT_SURFACE, SURFACES, surface_mesh
from .build import DEFAULT_THRESHOLD, MAX_BUILD_DEPTH, build_octree
from .errors import OctreeInputError
from .inputs import load_input
from .octree import LEAF, Octree
from .patches import depth_colors

OUTPUT_EXTENSIONS = (".ply", ".glb", ".obj", ".stl", ".off")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = command_parser("python -m model.octree", __doc__, [
        "python -m model.octree examples/airplane.obj --depth 7 --out airplane_patches.ply --stats airplane.json "
        "--color-by-depth",
        "python -m model.octree scan.xyz --depth 6 --full --out scan_octree.glb"])
    ap.add_argument("input", help="mesh (obj, off, ply, stl, glb) or point cloud (ply, xyz, txt, npy, npz)")
    ap.add_argument("--depth", type=int, required=True, help=f"max depth D (1..{MAX_BUILD_DEPTH})")
    ap.add_argument("--full", action="store_true", help="build the full O-CNN octree instead of the adaptive one")
    ap.add_argument("--threshold", type=float, default=DEFAULT_THRESHOLD,
                    help="split threshold delta hat in finest voxels (default sqrt(3)/2)")
    ap.add_argument("--points", type=int, default=None,
                    help="number of surface samples for a mesh (default: spacing of 1/3 finest voxel)")
    ap.add_argument("--out", required=True, help="mesh to write (.ply, .glb, .obj, .stl, .off)")
    ap.add_argument("--surface", choices=SURFACES, default=DEFAULT_SURFACE,
                    help=f"watertight: a closed, consistently oriented 2-manifold mesh; patches: one planar patch "
                         f"per leaf, the paper's output (default {DEFAULT_SURFACE})")
    ap.add_argument("--faces", type=int, default=None,
                    help="a face budget for the watertight surface, met by simplification that keeps it closed "
                         "(default: none)")
    ap.add_argument("--stats", default=None, help="write statistics as JSON here")
    ap.add_argument("--color-by-depth", action="store_true", help="colour the mesh by the depth of the leaves")
    ap.add_argument("--seed", type=int, default=0, help="seed of the mesh sampling")
    return ap.parse_args(argv)


def octree_stats(octree: Octree, seconds: float) -> dict:
    """The statistics the CLI writes: structure per depth and the patch errors in input units."""
    scale = octree.normalizations[0].scale
    err_all, err_above = [], []
    for lv in octree.levels:
        e = lv.error[(lv.label == LEAF) & np.isfinite(lv.error)]
        err_all.append(e)
        if lv.depth < octree.depth:
            err_above.append(e)
    cat = np.concatenate(err_all)
    above = np.concatenate(err_above) if err_above else np.zeros(0)
    return {
        "depth": octree.depth,
        "adaptive": octree.adaptive,
        "threshold": octree.threshold * scale,
        "threshold_voxels": octree.threshold * (1 << octree.depth),
        "nodes_per_depth": octree.nodes_per_depth(),
        "nonempty_per_depth": octree.nonempty_per_depth(),
        "leaves_per_depth": octree.leaves_per_depth(),
        "nodes": int(sum(octree.nodes_per_depth())),
        "max_patch_error": float(cat.max() * scale) if len(cat) else 0.0,
        "max_patch_error_above_max_depth": float(above.max() * scale) if len(above) else 0.0,
        "seconds": seconds,
    }


def run(args: argparse.Namespace) -> dict:
    ext = os.path.splitext(args.out)[1].lower()
    if ext not in OUTPUT_EXTENSIONS:
        raise OctreeInputError(f"--out must end in one of {', '.join(OUTPUT_EXTENSIONS)}, got '{ext or args.out}'")
    for target in filter(None, (args.out, args.stats)):
        folder = os.path.dirname(os.path.abspath(target))
        if not os.path.isdir(folder):
            raise OctreeInputError(f"{target}: the folder {folder} does not exist")
    if args.faces is not None and (args.faces < 4 or args.surface != "watertight"):
        raise OctreeInputError("--faces must be at least 4, with --surface watertight")
    if not 1 <= args.depth <= MAX_BUILD_DEPTH:
        raise OctreeInputError(f"--depth must be in 1..{MAX_BUILD_DEPTH}, got {args.depth}")
    loaded = load_input(args.input, args.depth, args.points, args.seed)
    t = time.perf_counter()
    octree = build_octree(loaded.cloud, args.depth, adaptive=not args.full, threshold=args.threshold,
                          neighbors=False, measure_leaves=True, sample_spacing=loaded.sample_spacing)
    seconds = time.perf_counter() - t
    m = surface_mesh(octree, args.surface, faces=args.faces)
    colors = depth_colors(m.vertex_depth) if args.color_by_depth else None
    mesh = trimesh.Trimesh(m.vertices, m.faces, vertex_colors=colors, process=False)
    data = mesh.export(file_type=ext[1:])
    write_atomic(args.out, data.encode() if isinstance(data, str) else data)
    stats = octree_stats(octree, seconds)
    stats.update(input=args.input, points=len(loaded.cloud), points_dropped=loaded.cloud.strays, input_kind=loaded.kind,
                 normals_estimated=loaded.normals_estimated, patches=int(sum(stats["leaves_per_depth"])),
                 surface=m.kind, triangles=int(len(m.faces)), closed=m.closed)
    if args.stats:
        write_atomic(args.stats, json_text(stats, indent=2).encode())
    return stats


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    try:
        stats = run(args)
    except OctreeInputError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(f"{args.out}: {stats['surface']} surface, {stats['triangles']} triangles"
          f"{' (closed)' if stats['closed'] else ''}, {stats['patches']} patches, {stats['nodes']} nodes, "
          f"depth {stats['depth']}, "
          f"max patch error {stats['max_patch_error']:.4g} (threshold {stats['threshold']:.4g}), "
          f"{stats['seconds']:.2f} s"
          + (f"; {stats['points_dropped']} point(s) far from the rest dropped" if stats["points_dropped"] else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
