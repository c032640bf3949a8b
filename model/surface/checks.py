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
    n = int(faces.max()) + 1
    a = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2]]).astype(np.int64)
    b = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0]]).astype(np.int64)
    # each undirected edge exactly twice, once each way: sorted keys pair up as (2u, 2u + 1)
    key = np.sort((np.minimum(a, b) * n + np.maximum(a, b)) * 2 + (a < b))
    return bool(key.size % 2 == 0 and np.all(key[0::2] % 2 == 0) and np.array_equal(key[1::2], key[0::2] + 1))


def is_manifold(faces: np.ndarray) -> bool:
    """Closed and consistently wound (:func:`is_closed`), and every vertex's faces form a single fan
    around it (no two surfaces pinched at one vertex): a closed oriented 2-manifold."""
    if not is_closed(faces):
        return False
    if not len(faces):
        return True

    f = len(faces)
    n = int(faces.max()) + 1
    corner = np.arange(3 * f).reshape(f, 3)                     # corner (face, j) holds vertex faces[face, j]
    # the corner at the start of each directed edge v -> w, and at the end of its reverse w -> v
    start = corner.ravel()
    key = faces.ravel() * n + np.roll(faces, -1, axis=1).ravel()
    back = np.roll(corner, -1, axis=1).ravel()                  # the corner of w in the same face
    order = np.argsort(key)
    rev_key = np.roll(faces, -1, axis=1).ravel() * n + faces.ravel()
    partner = order[np.searchsorted(key[order], rev_key)]       # the face edge w -> v, seen from v -> w
    # corners of v around the shared edge: (v in this face) ~ (v at the end of the partner edge)
    graph = coo_matrix((np.ones(3 * f, np.int8), (start, back[partner])), shape=(3 * f, 3 * f))
    fans, _ = connected_components(graph, directed=False)
    return fans == len(np.unique(faces))


def is_closed_embedded(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Closed and 2-manifold (:func:`is_manifold`) once vertices closer than :data:`WELD` of the box
    are merged, with no face collapsed by the merge: what a welding reader finds."""
    welded = weld(vertices, faces)
    collapsed = (welded[:, 0] == welded[:, 1]) | (welded[:, 1] == welded[:, 2]) | (welded[:, 0] == welded[:, 2])
    return not collapsed.any() and is_manifold(welded)
