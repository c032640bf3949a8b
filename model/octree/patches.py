"""Leaf patches of an octree: planar polygons (plane ∩ octant cube) and their triangle mesh."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from .geometry import MAX_POLYGON, cube_polygons
from .jit import compiled
from .octree import LEAF, Octree

DEPTH_COLORS = np.array([
    [90, 90, 90], [150, 150, 150], [110, 110, 110],            # depths 0-2 (never leaves in practice)
    [86, 180, 233], [0, 114, 178], [230, 159, 0], [0, 158, 115], [213, 94, 0],    # 3-7
    [204, 121, 167], [240, 228, 66], [120, 60, 160], [0, 0, 0], [170, 110, 40],  # 8-12
    [40, 200, 200], [200, 40, 40], [60, 60, 200], [250, 250, 250],                # 13-16
], dtype=np.uint8)
"""A colour per depth 0..16, for looking at which depth each patch came from: the Okabe-Ito
colour-blind-safe hues from depth 3, neighbouring depths in strongly different hues."""


@dataclass
class PatchSet:
    """Leaf patches in cube coordinates: convex polygons of 3..6 vertices (padded to 6)."""

    vertices: np.ndarray   # (P, 6, 3) float64, counter-clockwise about the normal
    count: np.ndarray      # (P,) int vertices per polygon
    normal: np.ndarray     # (P, 3) float64 unit normals
    offset: np.ndarray     # (P,) plane offset relative to the octant centre (cube units)
    center: np.ndarray     # (P, 3) octant centres
    size: np.ndarray       # (P,) octant edge lengths
    depth: np.ndarray      # (P,) int
    batch: np.ndarray      # (P,) int
    error: np.ndarray      # (P,) patch error (cube units; NaN if not measured)

    def __len__(self) -> int:
        return len(self.count)


def _level_polygons(octree: Octree):
    """Per depth with leaves, in depth order: the level, its leaves' rows, their unit normals,
    plane offsets and octant centres, and their polygons (:func:`cube_polygons`, about the centres)."""
    for lv in octree.levels:
        sel = np.flatnonzero(lv.label == LEAF)
        if len(sel) == 0:
            continue
        normal = lv.plane[sel, :3].astype(np.float64)
        normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-12)
        offset = lv.plane_offsets(sel)
        verts, count = cube_polygons(normal, offset, lv.size)
        yield lv, sel, normal, offset, lv.centers(sel), verts, count


def leaf_patches(octree: Octree) -> PatchSet:
    """The planar patch of every leaf (label LEAF) of every depth, for all shapes of the batch."""
    parts = []
    for lv, sel, normal, offset, centre, verts, count in _level_polygons(octree):
        parts.append((verts + centre[:, None], count, normal, offset, centre,
                      np.full(len(sel), lv.size), np.full(len(sel), lv.depth),
                      lv.batch[sel], lv.error[sel].astype(np.float64)))
    if not parts:
        e = np.zeros((0,))
        return PatchSet(np.zeros((0, MAX_POLYGON, 3)), e.astype(int), np.zeros((0, 3)), e,
                        np.zeros((0, 3)), e, e.astype(int), e.astype(int), e)
    cols = [np.concatenate(c) for c in zip(*parts)]
    return PatchSet(*cols)


def patch_triangles(patches: PatchSet) -> tuple[np.ndarray, np.ndarray]:
    """Fan triangulation: vertices (V, 3) and faces (F, 3) whose normals follow each patch's n."""
    p = len(patches)
    verts = patches.vertices.reshape(-1, 3)
    i = np.arange(1, MAX_POLYGON - 1)
    faces = np.stack([np.zeros_like(i), i, i + 1], axis=1)               # (4, 3)
    faces = faces[None] + (np.arange(p) * MAX_POLYGON)[:, None, None]    # (P, 4, 3)
    keep = i[None] + 1 < patches.count[:, None]                          # triangle (0, i, i+1)
    return verts, faces[keep]


@dataclass
class PatchMesh:
    """Triangles of all leaf patches: only the vertices the faces use, each patch its own."""

    vertices: np.ndarray             # (V, 3) float64
    faces: np.ndarray                # (F, 3) int64, counter-clockwise about each patch's normal
    vertex_depth: np.ndarray         # (V,) int octree depth of the patch each vertex belongs to


def patch_mesh(octree: Octree, world: bool = True) -> PatchMesh:
    """The leaf patches' triangle mesh, in the input's coordinates (one shape) unless ``world`` is
    False; the arrays every mesh writer starts from.  The patches of :func:`leaf_patches` in their
    order, each polygon's vertices in order and its fan (0, i, i + 1), written level by level by
    one compiled pass (the vertices ``(polygon + centre - 0.5) * scale + center`` in world
    coordinates, as :meth:`Normalization.to_world` computes them)."""
    if world and octree.batch_size != 1:
        raise ValueError("world coordinates need a single-shape octree; pass world=False")
    levels = [(lv.depth, verts, count, centre) for lv, _, _, _, centre, verts, count in _level_polygons(octree)]
    n_verts = sum(int(count.sum()) for _, _, count, _ in levels)
    n_faces = sum(int(np.maximum(count - 2, 0).sum()) for _, _, count, _ in levels)
    vertices, faces = np.empty((n_verts, 3)), np.empty((n_faces, 3), np.int64)
    depth = np.empty(n_verts, np.int64)
    norm = octree.normalizations[0] if world else None
    center = np.zeros(3) if norm is None else np.asarray(norm.center, dtype=np.float64)
    scale = 1.0 if norm is None else float(norm.scale)
    v = f = 0
    for d, verts, count, centre in levels:
        nv, nf = _write_patches(verts, count, centre, world, center, scale, v, f, vertices, faces)
        depth[v:v + nv] = d
        v, f = v + nv, f + nf
    return PatchMesh(vertices, faces, depth)


@compiled
def _write_patches(verts, count, centre, world, center, scale, v, f, vertices, faces) -> tuple[int, int]:
    """One level's polygons into ``vertices`` from row ``v`` and their fans into ``faces`` from row
    ``f``; returns how many of each were written."""
    v0, f0 = v, f
    for i in range(len(count)):
        first = v
        for j in range(count[i]):
            for a in range(3):
                x = verts[i, j, a] + centre[i, a]
                vertices[v, a] = (x - 0.5) * scale + center[a] if world else x
            v += 1
        for j in range(1, count[i] - 1):
            faces[f, 0], faces[f, 1], faces[f, 2] = first, first + j, first + j + 1
            f += 1
    return v - v0, f - f0


def depth_colors(depth: np.ndarray) -> np.ndarray:
    """RGBA uint8 colours (N, 4) of octree depths (:data:`DEPTH_COLORS`)."""
    return np.concatenate([DEPTH_COLORS[np.minimum(depth, 16)], np.full((len(depth), 1), 255, np.uint8)], axis=1)


def patches_to_mesh(octree: Octree, color_by_depth: bool = False, world: bool = True):
    """A trimesh of all leaf patches, in the input's coordinates (one shape) unless ``world`` is False."""

    m = patch_mesh(octree, world)
    colors = depth_colors(m.vertex_depth[m.faces[:, 0]]) if color_by_depth and len(m.faces) else None
    return trimesh.Trimesh(vertices=m.vertices, faces=m.faces, face_colors=colors, process=False)
