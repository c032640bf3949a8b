"""Dual marching cubes on the finest grid: one vertex per surface component of every cell,
placed by the leaf planes, one quad per grid edge that crosses the surface.

Configurations that would break manifoldness are first repaired (:func:`repair`), so each
vertex's quads close around it in one fan and every edge of the mesh has exactly two faces: the
mesh is closed and 2-manifold by construction, and its quads are wound with the outside on
their front.  A vertex is
the least-squares point of the planes met on its component's crossing edges (the Hermite data:
where each edge crosses its leaf's plane, with that plane's normal), kept inside its cell: sharp
edges and corners where two or three leaf planes meet stay sharp.
"""

from __future__ import annotations

import numpy as np

from ..octree.jit import compiled
from .flood import configurations, repaired
from .graph import close_pairs
from .grid import Grid, Leaves
from .tables import COMPONENTS, CORNER_COMPONENT, REPAIR


def repair(inside: np.ndarray, max_rounds: int = 64) -> tuple[np.ndarray, np.ndarray, int]:
    """Turn outside corners inside until no cell needs a repair (:data:`REPAIR`) and no outside
    region is cut off from the border (a repair can close one); returns the corners, the cells'
    configurations and how many corners were turned.  Corners only ever turn inside (never those
    of the grid's border), so this ends; in the unseen case that it runs out of rounds, the mesh
    is made as it stands and :func:`model.surface.is_closed` says whether it is closed.  Compiled
    (:func:`.flood.repaired`): each round re-judges only the cells around the corners turned."""
    inside, turned, _ = repaired(inside, REPAIR, max_rounds)
    return inside, configurations(inside), turned


def contour(grid: Grid, leaves: Leaves, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (V, 3) in cube coordinates (in the unit cube), quads (Q, 4) of the surface between
    the inside and outside corners, wound with the outside in front, and each vertex's array cell
    (V, 3) in ``grid``."""
    inside, config, _ = repair(inside)
    first = np.zeros(config.size + 1, np.int64)
    np.cumsum(COMPONENTS[config].ravel(), out=first[1:])
    rings, cells, edges = [], [], []
    for axis in range(3):
        step = np.zeros(3, np.int64)
        step[axis] = 1
        a = inside[:inside.shape[0] - step[0], :inside.shape[1] - step[1], :inside.shape[2] - step[2]]
        b = inside[step[0]:, step[1]:, step[2]:]
        p = np.argwhere(a != b)                                  # edge from corner p to p + step
        if not len(p):
            continue
        out_first = ~a[p[:, 0], p[:, 1], p[:, 2]]               # the surface faces -axis here
        inner = p + np.where(out_first[:, None], step, 0)        # the edge's inside corner
        u, w = [k for k in range(3) if k != axis]
        ring, around = [], []
        for du, dw in ((0, 0), (1, 0), (1, 1), (0, 1)):         # the 4 cells around the edge, in turn
            q = p.copy()
            q[:, u] -= du
            q[:, w] -= dw
            flat = np.ravel_multi_index(q.T, config.shape)
            local = inner - q
            comp = CORNER_COMPONENT[config.ravel()[flat], local[:, 0] + 2 * local[:, 1] + 4 * local[:, 2]]
            ring.append(first[flat] + comp)
            around.append(flat)
        ring = np.stack(ring, 1)
        flip = out_first ^ (axis == 1)                           # the cyclic order's handedness per axis
        ring[flip] = ring[flip][:, ::-1]
        rings.append(ring)
        cells.append(np.stack(around, 1))
        edges.append((p, np.full(len(p), axis), out_first))
    if not rings:
        return np.zeros((0, 3)), np.zeros((0, 4), np.int64), np.zeros((0, 3), np.int64)
    rings = np.concatenate(rings)
    cell = _vertex_cells(config.shape, first)
    verts = _place(grid, leaves, cell, np.concatenate(cells), *(np.concatenate(e) for e in zip(*edges)), rings)
    return np.clip(verts, 0.0, 1.0), rings, cell                 # the octree's cube is the domain


APART = 1e-3
"""How far (in cells) a vertex moves away from another that has its position."""


def apart(verts: np.ndarray, faces: np.ndarray, cell_centre: np.ndarray, h: float, rounds: int = 6) -> np.ndarray:
    """The vertices, each one within ``APART h / 10`` of another (vertices of neighbouring cells
    clipped onto their common face, edge or corner, or two components of one cell placed by the
    same planes) moved by :data:`APART` cells: first towards its own cell's centre (``cell_centre``);
    then, of each pair still together, the vertex of the lower index alone towards the centre of
    its own faces (two vertices that move alike stay together), in rounds until none is.  A
    reader that merges vertices by position (as trimesh, Blender and slicers do) then finds the
    same mesh.  Vertices move towards points inside the unit cube, so they stay in it."""
    out = verts
    for r in range(rounds):
        pairs = close_pairs(out, 0.1 * APART * h)
        if not len(pairs):
            break
        near = np.unique(pairs) if r == 0 else np.unique(pairs.min(1))
        step = (cell_centre[near] if r == 0 else _face_centres(verts, faces, near)) - out[near]
        out = out.copy()
        out[near] += APART * h * step / np.maximum(np.linalg.norm(step, axis=1, keepdims=True), 1e-30)
    return out


def _face_centres(verts: np.ndarray, faces: np.ndarray, which: np.ndarray) -> np.ndarray:
    """(len(which), 3): for the vertices ``which``, the mean of the centroids of the faces around each."""
    rows = np.flatnonzero(np.isin(faces, which).any(1))
    around, middle = faces[rows], verts[faces[rows]].mean(1)
    index = np.searchsorted(which, around.ravel())
    mine = (index < len(which)) & (which[np.minimum(index, len(which) - 1)] == around.ravel())
    total = np.zeros((len(which), 3))
    np.add.at(total, index[mine], np.repeat(middle, faces.shape[1], axis=0)[mine])
    return total / np.maximum(np.bincount(index[mine], minlength=len(which)), 1)[:, None]


BACK = 0.25
"""How far behind a plane (in cells) the back of a part thinner than a cell is put."""


def _place(grid: Grid, leaves: Leaves, vertex_cell: np.ndarray, cells: np.ndarray, p: np.ndarray,
           axis: np.ndarray, out_first: np.ndarray, rings: np.ndarray) -> np.ndarray:
    """Each vertex at the least-squares point of the leaf planes around its crossing edges (the
    planes of the leaves owning the 4 cells around each edge: one plane inside a leaf, two or
    three where leaves meet at an edge or corner), held by a small pull towards the mean crossing
    point where the planes leave a direction free (Tikhonov), and kept inside its cell.  An edge
    with no leaf around it (a surface the sign field closed) constrains its vertices to the plane
    across the edge through its inside corner; and where a leaf's plane does not cross the edge
    it meets (the end of a thin part, a closed gap), its point is the inside corner too: such
    surfaces close at the last inside corner, not further.

    Where a plane faces away from the surface it meets (its normal against the edge's direction
    from inside to outside: the back of a part thinner than a cell, which one plane stands for),
    the vertex is held :data:`BACK` cells behind the plane instead, and may leave its cell by up to
    a cell to get there: such parts come out about :data:`BACK` cells thick, not a whole cell."""
    h = grid.h
    nverts = len(vertex_cell)
    a_pos = grid.corner_positions(p)
    direction = np.eye(3)[axis]
    owners = grid.owner.ravel()[cells]                          # (E, 4) leaf or -1
    free = (owners < 0).all(1)                                   # no leaf around the edge
    inner = a_pos + out_first[:, None] * h * direction        # the edge's inside corner
    # per edge: the sums over its planes (each owner of the 4 cells counts once per cell)
    quad = np.zeros((len(p), 6))                                 # n n^T: xx xy xz yy yz zz
    lin = np.zeros((len(p), 3))                                  # -c n
    mass = np.zeros((len(p), 3))                                 # crossing points
    hits = np.zeros(len(p))
    back = np.zeros(len(p), bool)
    outward = np.where(out_first, -1.0, 1.0)                     # along the axis, inside -> outside
    for k in range(4):
        o = owners[:, k]
        has = o >= 0
        use = has | (free & (k == 0))                           # a free edge constrains once
        n = np.where(has[:, None], leaves.normal[np.maximum(o, 0)], direction)
        c = np.where(has, leaves.const[np.maximum(o, 0)], -np.einsum("ij,ij->i", direction, inner))
        behind = has & (n[np.arange(len(p)), axis] * outward < 0)
        back |= behind & use
        c = c + np.where(behind, BACK * h, 0.0)                   # n.x + c = -BACK h: just behind the plane
        fa = np.einsum("ij,ij->i", n, a_pos) + c                 # the plane n.x + c = 0 along the edge
        fb = fa + n[np.arange(len(p)), axis] * h
        crosses = (fa <= 0) != (fb <= 0)
        t = np.where(crosses, fa / np.where(crosses, fa - fb, 1.0), out_first.astype(np.float64))
        w = use.astype(np.float64)
        quad += w[:, None] * n[:, [0, 0, 0, 1, 1, 2]] * n[:, [0, 1, 2, 1, 2, 2]]
        lin -= (w * c)[:, None] * n
        mass += w[:, None] * (a_pos + (t * h)[:, None] * direction)
        hits += w
    tot = _ring_sums(rings, np.concatenate([quad, lin, mass, hits[:, None]], 1), nverts)
    v, edge = rings.T.ravel(), np.tile(np.arange(len(p)), 4)     # every vertex around each edge
    xx, xy, xz, yy, yz, zz = tot[:, :6].T
    point = tot[:, 9:12] / np.maximum(tot[:, 12:13], 1.0)
    reg = 0.02 * (xx + yy + zz)[:, None] / 3.0 + 1e-12          # the pull towards the mean point
    b = tot[:, 6:9] + reg * point
    x = _solve_symmetric(xx + reg[:, 0], xy, xz, yy + reg[:, 0], yz, zz + reg[:, 0], b)
    lo = grid.corner_positions(vertex_cell)
    reach = h * (np.bincount(v, back[edge], minlength=nverts) > 0)   # a back vertex may leave its cell
    return np.clip(x, lo - reach[:, None], lo + h + reach[:, None])


@compiled
def _ring_sums(rings: np.ndarray, rows: np.ndarray, count: int) -> np.ndarray:
    """(count, C): for every vertex, the sum of ``rows`` (E, C) of the edges whose ring (E, 4) it
    is in, added ring position by ring position, edge by edge (the order of ``np.bincount`` over
    ``rings.T.ravel()``: the same sums)."""
    out = np.zeros((count, rows.shape[1]))
    for k in range(rings.shape[1]):
        for e in range(len(rings)):
            for j in range(rows.shape[1]):
                out[rings[e, k], j] += rows[e, j]
    return out


def _solve_symmetric(xx, xy, xz, yy, yz, zz, b: np.ndarray) -> np.ndarray:
    """x with A x = b for many symmetric positive definite 3x3 A (adjugate over determinant)."""
    c00, c01, c02 = yy * zz - yz * yz, xz * yz - xy * zz, xy * yz - xz * yy
    c11, c12, c22 = xx * zz - xz * xz, xy * xz - xx * yz, xx * yy - xy * xy
    det = xx * c00 + xy * c01 + xz * c02
    inv = 1.0 / det
    return np.stack([c00 * b[:, 0] + c01 * b[:, 1] + c02 * b[:, 2],
                     c01 * b[:, 0] + c11 * b[:, 1] + c12 * b[:, 2],
                     c02 * b[:, 0] + c12 * b[:, 1] + c22 * b[:, 2]], 1) * inv[:, None]


def _vertex_cells(shape: tuple, first: np.ndarray) -> np.ndarray:
    """The (padded) cell index of every vertex."""
    owner = np.repeat(np.arange(len(first) - 1), np.diff(first))
    return np.stack(np.unravel_index(owner, shape), 1)
