"""Octants whose label changed when the patch's closing edge got its boundary probes, each
checked against a dense reference of the mesh.

Before commit 22afaf2 the boundary probes of a polygon with fewer than 6 vertices skipped its
closing edge (vertex n-1 back to vertex 0): that edge's probes all sat on vertex n-1.  Probing the edge
can only add probes, so a change can only turn a leaf into a split.  For every octant whose
label differs between the two rules (same points, same depth), this script measures the
octant's patch against 2M samples of the mesh itself: the Hausdorff distance between the patch
(probed every size/64) and the mesh samples inside the octant.  The change is right when that
distance is above the split threshold.

    python -m bench.octree_label_changes [--meshes ...] [--mesh-dir DIR] [--depths 6 7 8]
                                         [--points 100000] [--dense 2000000]
"""

from __future__ import annotations

import os
import sys
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Iterator

import numpy as np
import trimesh
from scipy.spatial import cKDTree

import model.octree.patch_error as patch_error
from bench.octree_build import DEFAULT_MESH_DIR, mesh_files, mesh_samples
from model.cli import command_parser
from model.octree import LEAF, SPLIT, build_octree
from model.octree.geometry import MAX_POLYGON, cube_polygons, patch_probes, polygon_distance
from model.octree.octree import Octree


@dataclass
class Change:
    """One octant decided differently by the two rules, and what the dense reference says."""

    depth: int
    key: int
    old: int                 # label without the closing edge's probes
    new: int                 # label with them
    dense_ratio: float       # dense Hausdorff distance / threshold

    @property
    def right(self) -> bool:
        return (self.new == SPLIT) == (self.dense_ratio > 1.0)


@contextmanager
def closing_edge_unprobed() -> Iterator[None]:
    """Build with the previous rule: the last edge of a polygon with < 6 vertices has length 0."""
    def previous(normal, offset, verts, count, size, spacing):
        probes = patch_probes(normal, offset, verts, count, size, spacing)
        k = np.arange(len(probes.edge_poly)) - np.searchsorted(probes.edge_poly, probes.edge_poly)
        probes.edge_b = verts[probes.edge_poly, (k + 1) % MAX_POLYGON]
        return probes

    patch_error.patch_probes, original = previous, patch_error.patch_probes
    try:
        yield
    finally:
        patch_error.patch_probes = original


def dense_hausdorff(octree: Octree, depth: int, node: int, dense: np.ndarray) -> float:
    """Hausdorff distance between node's patch and the dense samples (cube units) inside it."""
    lv = octree.levels[depth]
    size = lv.size
    centre = lv.centers()[node]
    inside = np.all(np.floor(dense / size) == np.floor(centre / size), axis=1)
    local = dense[inside] - centre
    normal = lv.plane[node, :3].astype(np.float64)
    normal /= np.linalg.norm(normal)
    offset = lv.plane_offsets()[node]
    verts, count = cube_polygons(normal[None], np.array([offset]), size)
    probes = patch_probes(normal[None], np.array([offset]), verts, count, size, size / 64)
    pts = np.concatenate([probes.grid_points(np.arange(len(probes.grid))),
                          probes.edge_points(np.arange(len(probes.edge_poly) * probes.per_edge))],
                         axis=1).T
    if len(local) == 0:
        return np.inf
    patch_to_surface = cKDTree(local).query(pts)[0].max()
    surface_to_patch = polygon_distance(local, np.repeat(normal[None], len(local), 0),
                                        np.full(len(local), offset),
                                        np.repeat(verts, len(local), 0)).max()
    return float(max(patch_to_surface, surface_to_patch))


def label_changes(mesh_path: str, depth: int, points: int, dense: int) -> tuple[int, list[Change]]:
    """(octants of the new octree, changes between the two rules with their dense verdicts)."""
    mesh = trimesh.load(mesh_path, force="mesh")
    cloud = mesh_samples(mesh, points)
    new = build_octree(cloud, depth, neighbors=False)
    with closing_edge_unprobed():
        old = build_octree(cloud, depth, neighbors=False)
    dense_pts = new.normalizations[0].to_cube(mesh_samples(mesh, dense, seed=1)[0])
    changes = []
    for a, b in zip(old.levels, new.levels):
        common, ia, ib = np.intersect1d(a.key, b.key, return_indices=True)
        for i, j, key in zip(ia, ib, common):
            if a.label[i] != b.label[j]:
                ratio = dense_hausdorff(new, b.depth, j, dense_pts) / new.threshold
                changes.append(Change(b.depth, int(key), int(a.label[i]), int(b.label[j]), ratio))
    return sum(new.nodes_per_depth()), changes


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.octree_label_changes", __doc__, [
        "python -m bench.octree_label_changes --mesh-dir ../shared/meshes"])
    ap.add_argument("--meshes", nargs="*", default=None, help="file names in --mesh-dir (default all)")
    ap.add_argument("--mesh-dir", default=DEFAULT_MESH_DIR,
                    help="folder of the meshes (default: ../shared/meshes beside the checkout)")
    ap.add_argument("--depths", type=int, nargs="+", default=[6, 7, 8], help="octree depths (default 6 7 8)")
    ap.add_argument("--points", type=int, default=100_000, help="points sampled per mesh for the build (default 100000)")
    ap.add_argument("--dense", type=int, default=2_000_000, help="mesh samples of the dense reference (default 2000000)")
    args = ap.parse_args(argv)
    names = args.meshes or mesh_files(args.mesh_dir)
    print(f"{'mesh':30s} depth  octants  changed  leaf->split  right  dense/threshold")
    total = wrong = 0
    for name in names:
        for depth in args.depths:
            n, changes = label_changes(os.path.join(args.mesh_dir, name), depth, args.points,
                                       args.dense)
            total += len(changes)
            wrong += sum(not c.right for c in changes)
            ratios = ", ".join(f"{c.dense_ratio:.1f}" for c in changes)
            print(f"{name:30s} {depth:5d} {n:8d} {len(changes):8d} "
                  f"{sum(c.old == LEAF and c.new == SPLIT for c in changes):11d} "
                  f"{sum(c.right for c in changes):6d}  {ratios}", flush=True)
    print(f"\n{total} octants changed, {total - wrong} right against the dense reference")
    return 0 if wrong == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
