"""What a closed mesh must satisfy, checked on the result rather than assumed: in its index
buffer (:func:`is_closed`, :func:`is_manifold`) and as embedded in space, as a reader that merges
vertices by position sees it (:func:`is_closed_embedded`)."""

from __future__ import annotations

import numpy as np

from ..octree.geometry import bounding_box
from ..octree.jit import compiled
from .graph import close_pairs, components

WELD = 1e-7
"""Vertices closer than this share of the bounding box's diagonal are one point to a reader that
merges by position (trimesh merges at 1e-8 absolute; Blender's "merge by distance" at 1e-4 of a
unit; slicers weld likewise)."""


def weld(vertices: np.ndarray, faces: np.ndarray, tolerance: float = WELD) -> np.ndarray:
    """``faces`` renumbered so that vertices within ``tolerance`` of the bounding box's diagonal of
    one another (transitively) are one vertex, as a welding reader loads the mesh."""
    if not len(vertices):
        return faces
    lo, hi = bounding_box(vertices)
    diag = float(np.linalg.norm(hi - lo))
    pairs = close_pairs(vertices, tolerance * max(diag, 1e-300))
    if not len(pairs):
        return faces
    return components(len(vertices), pairs[:, 0], pairs[:, 1])[faces]


def is_closed(faces: np.ndarray) -> bool:
    """Every directed edge appears once and its reverse once: closed and consistently wound."""
    if not len(faces):
        return True
    return not _lone_vertex(faces) and not edge_faults(faces).any()


def _lone_vertex(faces: np.ndarray) -> bool:
    """A vertex of one face: its two edges there are open (a patch mesh, found at once)."""
    return bool((np.bincount(faces.ravel()) == 1).any())


def edge_faults(faces: np.ndarray, n: int | None = None) -> np.ndarray:
    """(3F,) bool, one per directed edge ``faces[i, j] -> faces[i, (j + 1) % 3]`` (in the order of
    ``faces.ravel()``): its edge does not have exactly two faces that traverse it in opposite
    directions (the edge ``v -> w`` once and ``w -> v`` once).  ``n``: more than the largest
    vertex index."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    n = int(faces.max()) + 1 if n is None else n
    if not len(faces):
        return np.zeros(0, bool)
    start, nxt, _ = _corners(faces, n)
    return _edge_faults(faces, start, nxt)


def fan_counts(faces: np.ndarray, n: int | None = None) -> np.ndarray:
    """(n,): how many fans each vertex's faces form (0 for a vertex no face uses; ``n``: more than
    the largest vertex index): two faces at a vertex ``v`` are in one fan when one has the edge
    ``v -> w`` and the other ``w -> v``.  Exact for a vertex whose every edge has two faces, one
    each way (a vertex with a faulty edge is not a manifold's anyway)."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    n = int(faces.max()) + 1 if n is None else n
    if not len(faces):
        return np.zeros(n, np.int64)
    start, nxt, prv = _corners(faces, n)
    return _fan_counts(start, nxt, prv)


def manifold_faults(faces: np.ndarray, n: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """:func:`edge_faults` and :func:`fan_counts` together, from one table of corners."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    n = int(faces.max()) + 1 if n is None else n
    if not len(faces):
        return np.zeros(0, bool), np.zeros(n, np.int64)
    start, nxt, prv = _corners(faces, n)
    return _edge_faults(faces, start, nxt), _fan_counts(start, nxt, prv)


@compiled
def _corners(faces: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Each vertex's corners, grouped by vertex (``start``: (n + 1,) offsets, vertices ascending,
    each vertex's corners in the order of ``faces.ravel()``): the next and the previous vertex
    of the corner's face."""
    start = np.zeros(n + 1, np.int64)
    for v in faces.ravel():
        start[v + 1] += 1
    for v in range(n):
        start[v + 1] += start[v]
    fill = start[:-1].copy()
    nxt = np.empty(3 * len(faces), np.int64)
    prv = np.empty(3 * len(faces), np.int64)
    for f in range(len(faces)):
        for j in range(3):
            v = faces[f, j]
            nxt[fill[v]] = faces[f, (j + 1) % 3]
            prv[fill[v]] = faces[f, (j + 2) % 3]
            fill[v] += 1
    return start, nxt, prv


@compiled
def _edge_faults(faces: np.ndarray, start: np.ndarray, nxt: np.ndarray) -> np.ndarray:
    wrong = np.empty(3 * len(faces), np.bool_)
    for f in range(len(faces)):
        for j in range(3):
            a, b = faces[f, j], faces[f, (j + 1) % 3]
            ab = 0
            for s in range(start[a], start[a + 1]):
                ab += nxt[s] == b
            ba = 0
            for s in range(start[b], start[b + 1]):
                ba += nxt[s] == a
            wrong[3 * f + j] = not (ab == 1 and ba == 1)
    return wrong


@compiled
def _fan_counts(start: np.ndarray, nxt: np.ndarray, prv: np.ndarray) -> np.ndarray:
    n = len(start) - 1
    out = np.zeros(n, np.int64)
    parent = np.empty(64, np.int64)
    for v in range(n):
        a, d = start[v], start[v + 1] - start[v]
        if d > len(parent):
            parent = np.empty(2 * d, np.int64)
        for i in range(d):
            parent[i] = i
        fans = d
        for i in range(d):                          # the face with v -> w and the one with w -> v
            for j in range(d):
                if i != j and nxt[a + i] == prv[a + j]:
                    ri, rj = i, j
                    while parent[ri] != ri:
                        ri = parent[ri]
                    while parent[rj] != rj:
                        rj = parent[rj]
                    if ri != rj:
                        parent[rj] = ri
                        fans -= 1
        out[v] = fans
    return out


def is_manifold(faces: np.ndarray) -> bool:
    """Closed and consistently wound (:func:`is_closed`), and every vertex's faces form a single fan
    around it (no two surfaces pinched at one vertex): a closed oriented 2-manifold."""
    if not len(faces):
        return True
    if _lone_vertex(faces):
        return False
    wrong, fans = manifold_faults(faces)
    return not wrong.any() and bool((fans <= 1).all())


def is_closed_embedded(vertices: np.ndarray, faces: np.ndarray) -> bool:
    """Closed and 2-manifold (:func:`is_manifold`) once vertices closer than :data:`WELD` of the box
    are merged, with no face collapsed by the merge: what a welding reader finds."""
    welded = weld(vertices, faces)
    collapsed = (welded[:, 0] == welded[:, 1]) | (welded[:, 1] == welded[:, 2]) | (welded[:, 0] == welded[:, 2])
    return not collapsed.any() and is_manifold(welded)
