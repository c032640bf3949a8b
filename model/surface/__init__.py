"""A closed surface from a decoded octree: the leaf planes' Hermite data contoured on the finest
grid (dual marching cubes), with inside and outside decided by the planes and by reachability,
then the vertices merged leaf by leaf where the surface stays closed, manifold and within a
third of a cell of the contour (:mod:`.clusters`): a large flat leaf becomes a few large faces.

The patch mesh of :mod:`model.octree.patches` is the paper's output: one planar polygon per leaf,
with cracks between them.  :func:`watertight_mesh` returns instead a mesh that is closed,
consistently wound with the outside in front, 2-manifold (also as embedded: no two vertices at
one position) and of positive volume, and whose vertices lie on the leaf planes where the planes
cross (sharp edges stay sharp); parts thinner than a cell are kept as closed slabs about one cell
thick.  Faces may cross other faces where neighbouring leaves' planes disagree (measured by
``bench.surface``).  NumPy/SciPy only (no torch): the CLI,
evaluation and the service call the same function.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..octree import Octree
from ..octree.patches import patch_mesh
from .checks import is_closed, is_closed_embedded
from .clusters import cluster, triangulate
from .dmc import apart, contour
from .graph import components
from .grid import Grid, Leaves, build_grid, leaves_of, rasterise
from .orient import orient
from .sign import inside_corners
from .simplify import simplify

SURFACES = ("watertight", "patches")
"""The surfaces a decoded octree can be meshed as: closed (this package) or the paper's patches."""
DEFAULT_SURFACE = "patches"
"""What the service and the command lines return unless asked otherwise.  The closed surface is
one parameter away; it is not the default because on the shipped models' outputs it is less
accurate than the patches (Chamfer 3% higher for image -> shape, 10-11% for completion, F-score
about 0.01 lower; docs/results.md, "Closed surfaces"), has more faces and takes longer to make."""
MIN_COMPONENT_FACES = 20
"""Components with fewer faces are dropped (a bubble around a single grid corner has 12)."""


@dataclass(frozen=True)
class SurfaceMesh:
    """An indexed triangle mesh: ``faces`` index ``vertices`` and are wound counter-clockwise seen
    from outside (patches: about their plane's normal).  ``vertex_depth``: the octree depth of
    the leaf each vertex comes from.  ``closed``: every edge has exactly two faces that traverse it
    in opposite directions and every vertex's faces form one fan, also once vertices at the same
    position are merged as welding readers do (checked on the result, not assumed:
    :func:`model.surface.checks.is_closed_embedded`)."""

    kind: str                # one of SURFACES
    vertices: np.ndarray     # (V, 3) float64
    faces: np.ndarray        # (F, 3) int64
    vertex_depth: np.ndarray  # (V,) int
    closed: bool


def surface_mesh(octree: Octree, kind: str = DEFAULT_SURFACE, world: bool = True,
                 faces: int | None = None) -> SurfaceMesh:
    """The mesh of a single-shape octree's leaves, as ``kind`` (:data:`SURFACES`), in the input's
    coordinates unless ``world`` is False (then in the unit cube).  ``faces``: a face budget for
    the closed surface, met by simplification that keeps it closed (:mod:`model.surface.simplify`)."""
    if kind not in SURFACES:
        raise ValueError(f"surface must be one of {', '.join(SURFACES)}, got {kind!r}")
    if kind == "patches":
        if faces is not None:
            raise ValueError("a face budget applies to the watertight surface only (patches are one per leaf)")
        m = patch_mesh(octree, world)
        return SurfaceMesh(kind, m.vertices, m.faces, m.vertex_depth, is_closed(m.faces))
    m = watertight_mesh(octree, world)
    if faces is None or len(m.faces) <= faces:
        return m
    verts, tris, depth, _ = simplify(m.vertices, m.faces, faces, m.vertex_depth)
    return SurfaceMesh(m.kind, verts, tris, depth, is_closed_embedded(verts, tris))


def signed_grid(octree: Octree) -> tuple[Grid, Leaves, np.ndarray]:
    """The finest grid over a single-shape octree's leaves (which must exist), the leaves with
    their planes oriented (:mod:`.orient`), and which grid corners are inside (:mod:`.sign`): what
    the closed surface is contoured from."""
    leaves = leaves_of(octree)
    raster = rasterise(leaves)
    leaves, _ = orient(leaves, raster[1], 1.0 / (1 << octree.depth))
    grid = build_grid(leaves, octree.depth, raster=raster)
    return grid, leaves, inside_corners(grid, leaves)


def watertight_mesh(octree: Octree, world: bool = True, min_component_faces: int = MIN_COMPONENT_FACES,
                    merge: bool = True) -> SurfaceMesh:
    """The closed surface of a single-shape octree, in the input's coordinates unless ``world`` is
    False (then in the unit cube): the finest grid's contour with each leaf's vertices merged
    (:mod:`.clusters`) unless ``merge`` is False, or where the merged mesh is not closed as
    embedded (not seen, but checked) the contour unmerged.  Components of fewer than
    ``min_component_faces`` faces are dropped.  An octree without leaves gives an empty mesh."""
    if octree.batch_size != 1:
        raise ValueError("watertight_mesh needs a single-shape octree (split a batch first)")
    if not len(leaves_of(octree)):
        return SurfaceMesh("watertight", np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64), True)
    grid, leaves, inside = signed_grid(octree)
    verts, quads, cell = contour(grid, leaves, inside)
    if merge and len(quads):
        c = cluster(verts, quads, cell, grid, leaves)
        m = _finished(octree, grid, leaves, c.vertices, c.triangles, c.leaf, c.centre, world, min_component_faces)
        if m.closed:
            return m
    leaf = grid.owner[cell[:, 0], cell[:, 1], cell[:, 2]].astype(np.int64)
    centre = grid.corner_positions(cell) + grid.h / 2
    return _finished(octree, grid, leaves, verts, triangulate(verts, quads), leaf, centre, world, min_component_faces)


def _finished(octree: Octree, grid: Grid, leaves: Leaves, verts: np.ndarray, faces: np.ndarray, leaf: np.ndarray,
              centre: np.ndarray, world: bool, min_component_faces: int) -> SurfaceMesh:
    """The closed surface from its vertices (cube coordinates), triangles, each vertex's leaf and
    the centre of the cube it stands for: vertices at one position parted, small components
    dropped, checked as a welding reader loads it."""
    verts = apart(verts, faces, np.clip(centre, 0.0, 1.0), grid.h)
    depth = octree.depth - np.log2(np.where(leaf >= 0, leaves.cells[np.maximum(leaf, 0)], 1)).astype(np.int64)
    keep, faces = drop_small_components(len(verts), faces, min_component_faces)
    verts, depth = verts[keep], depth[keep]
    if world:
        verts = octree.normalizations[0].to_world(verts)
    return SurfaceMesh("watertight", verts, faces, depth, is_closed_embedded(verts, faces))


def drop_small_components(nverts: int, faces: np.ndarray, min_faces: int) -> tuple[np.ndarray, np.ndarray]:
    """The vertices to keep (a mask) and the faces renumbered, without the face-connected
    components of fewer than ``min_faces`` faces and without the vertices no face uses."""
    if not len(faces):
        return np.zeros(nverts, bool), faces
    edges = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]]])
    label = components(nverts, edges[:, 0], edges[:, 1])
    size = np.bincount(label[faces[:, 0]], minlength=label.max() + 1)
    faces = faces[size[label[faces[:, 0]]] >= min_faces]
    used = np.zeros(nverts, bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return used, remap[faces]
