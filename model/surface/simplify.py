"""Fewer faces for a closed surface, keeping it closed: manifold3d's edge-collapse simplification
(a collapse is made only when the surface moves by less than a tolerance and the mesh stays a
2-manifold), with the tolerance doubled until the mesh fits a face budget.  Where the mesh that
fits it has two surfaces touching (a thin part's sides collapsed onto each other: closed in its
index buffer, not as a reader that welds vertices by position sees it), the last one before it
that is closed as embedded is returned instead, with more faces than asked."""

from __future__ import annotations

import manifold3d
import numpy as np
from scipy.spatial import cKDTree

from ..octree.geometry import bounding_box
from .checks import is_closed, is_closed_embedded

START = 1e-4
"""The first tolerance tried, as a share of the mesh's bounding-box diagonal."""
LARGEST = 0.05
"""The largest tolerance tried: past it the mesh is returned with more faces than asked."""


def simplify(vertices: np.ndarray, faces: np.ndarray, max_faces: int,
             vertex_depth: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, float]:
    """(vertices, faces, vertex_depth, tolerance) of the closed mesh with at most ``max_faces``
    faces (or as few as a tolerance of :data:`LARGEST` of the diagonal, and staying closed as
    embedded, allow).  The tolerance is how far the surface may have moved.  ``vertex_depth`` is carried over from the nearest
    original vertex."""

    if max_faces < 4:
        raise ValueError(f"faces must be at least 4 (a tetrahedron), got {max_faces}")
    if len(faces) <= max_faces:
        return vertices, faces, vertex_depth, 0.0
    solid = manifold3d.Manifold(manifold3d.Mesh(vert_properties=np.asarray(vertices, np.float32),
                                                tri_verts=np.asarray(faces, np.uint32)))
    if solid.status() != manifold3d.Error.NoError:
        raise ValueError(f"the mesh is not a closed 2-manifold ({solid.status()}); it cannot be simplified")
    lo, hi = bounding_box(vertices)
    diag = float(np.linalg.norm(hi - lo))
    tolerance = START * diag
    best = (np.asarray(vertices, np.float64), np.asarray(faces, np.int64), 0.0)
    while True:
        solid = solid.simplify(tolerance)
        out = solid.to_mesh()
        verts = np.asarray(out.vert_properties, np.float64)[:, :3]
        tris = np.asarray(out.tri_verts, np.int64)
        if not is_closed(tris):
            raise RuntimeError("manifold3d returned a mesh that is not closed")
        if is_closed_embedded(verts, tris):       # not where two sides of a thin part were made to touch
            best = (verts, tris, tolerance)
        if len(tris) <= max_faces or tolerance >= LARGEST * diag:
            break
        tolerance *= 2.0
    verts, tris, tolerance = best
    depth = None if vertex_depth is None else vertex_depth[cKDTree(vertices).query(verts)[1]]
    return verts, tris, depth, tolerance
