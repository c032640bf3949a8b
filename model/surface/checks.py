"""What a closed mesh must satisfy, checked on the result rather than assumed: in its index
buffer (:func:`is_closed`, :func:`is_manifold`) and as embedded in space, as a reader that merges
vertices by position sees it (:func:`is_closed_embedded`)."""

from __future__ import annotations

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

WELD = 1e-7
"""Vertices closer than this share of the bounding box's diagonal are one point to a reader that
merges by position (trimesh merges at 1e-8 absolute; Blender's "merge by distance" at 1e-4 of a
unit; slicers weld likewise)."""


def weld(vertices: np.ndarray, faces: np.ndarray, tolerance: float = WELD) -> np.ndarray:
    """``faces`` renumbered so that vertices within ``tolerance`` of the bounding box's diagonal of
    one another (transitively) are one vertex, as a welding reader loads the mesh."""
    if not len(vertices):
        return faces
    diag = float(np.linalg.norm(vertices.max(0) - vertices.min(0)))
    pairs = cKDTree(vertices).query_pairs(tolerance * max(diag, 1e-300), output_type="ndarray")
    if not len(pairs):
        return faces
    graph = coo_matrix((np.ones(len(pairs), np.int8), (pairs[:, 0], pairs[:, 1])), shape=(len(vertices),) * 2)
    _, label = connected_components(graph, directed=False)
    return label[faces]


def is_closed(faces: np.ndarray) -> bool:
    """Every directed edge appears once and its reverse once: closed and consistently wound."""
    if not len(faces):
        return True
    if (np.bincount(faces.ravel()) == 1).any():     # a vertex of one face: its two edges there are open
        return False                                # (a patch mesh, at once, without the sort)
    return not edge_faults(faces).any()


def edge_faults(faces: np.ndarray, n: int | None = None) -> np.ndarray:
    """(3F,) bool, one per directed edge ``faces[i, j] -> faces[i, (j + 1) % 3]`` (in the order of
    ``faces.ravel()``): its edge does not have exactly two faces that traverse it in opposite
    directions.  ``n``: more than the largest vertex index."""
    n = int(faces.max()) + 1 if n is None else n
    a = faces.ravel().astype(np.int64)
    b = np.roll(faces, -1, axis=1).ravel().astype(np.int64)
    undirected = np.minimum(a, b) * n + np.maximum(a, b)
    order = np.argsort(undirected, kind="stable")
    sorted_key = undirected[order]
    group = np.cumsum(np.r_[True, sorted_key[1:] != sorted_key[:-1]]) - 1
    forward = np.bincount(group, (a < b)[order])
    wrong = np.empty(len(a), bool)
    wrong[order] = ((np.bincount(group) != 2) | (forward != 1))[group]
    return wrong


def fan_counts(faces: np.ndarray, n: int | None = None) -> np.ndarray:
    """(n,): how many fans each vertex's faces form (0 for a vertex no face uses; ``n``: more than
    the largest vertex index).  Exact for a vertex whose every edge has two faces, one each way: a
    corner is joined only to corners of its own vertex, so another vertex's faulty edge changes
    nothing here."""
    n = int(faces.max()) + 1 if n is None else n
    f = len(faces)
    corner = np.arange(3 * f).reshape(f, 3)                     # corner (face, j) holds vertex faces[face, j]
    # the corner at the start of each directed edge v -> w, and at the end of its reverse w -> v
    key = faces.ravel().astype(np.int64) * n + np.roll(faces, -1, axis=1).ravel()
    back = np.roll(corner, -1, axis=1).ravel()                  # the corner of w in the same face
    order = np.argsort(key)
    rev = np.roll(faces, -1, axis=1).ravel().astype(np.int64) * n + faces.ravel()
    partner = order[np.minimum(np.searchsorted(key[order], rev), 3 * f - 1)]   # the edge w -> v, where there is one
    paired = key[partner] == rev
    # corners of v around the shared edge: (v in this face) ~ (v at the end of the partner edge)
    graph = coo_matrix((np.ones(int(paired.sum()), np.int8), (corner.ravel()[paired], back[partner][paired])),
                       shape=(3 * f, 3 * f))
    _, fan = connected_components(graph, directed=False)
    pairs = np.unique(faces.ravel().astype(np.int64) * (3 * f) + fan)
    return np.bincount(pairs // (3 * f), minlength=n)


def is_manifold(faces: np.ndarray) -> bool:
    """Closed and consistently wound (:func:`is_closed`), and every vertex's faces form a single fan
    around it (no two surfaces pinched at one vertex): a closed oriented 2-manifold."""
    if not is_closed(faces):
        return False
    return not len(faces) or bool((fan_counts(faces) <= 1).all())


def is_closed_embedded(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Closed and 2-manifold (:func:`is_manifold`) once vertices closer than :data:`WELD` of the box
    are merged, with no face collapsed by the merge: what a welding reader finds."""
    welded = weld(vertices, faces)
    collapsed = (welded[:, 0] == welded[:, 1]) | (welded[:, 1] == welded[:, 2]) | (welded[:, 0] == welded[:, 2])
    return not collapsed.any() and is_manifold(welded)
