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

from .grid import CORNER_OFFSETS, Grid, Leaves
from .sign import fill_cavities
from .tables import COMPONENTS, CORNER_COMPONENT, REPAIR


def configurations(inside: np.ndarray) -> np.ndarray:
    """The 8-bit configuration of every cell (bit c set when corner c is inside)."""
    mx, my, mz = (s - 1 for s in inside.shape)
    config = np.zeros((mx, my, mz), np.uint8)
    for c, (x, y, z) in enumerate(CORNER_OFFSETS):
        config |= inside[x:x + mx, y:y + my, z:z + mz].astype(np.uint8) << np.uint8(c)
    return config


def repair(inside: np.ndarray, max_rounds: int = 64) -> tuple[np.ndarray, np.ndarray, int]:
    """Turn outside corners inside until no cell needs a repair (:data:`REPAIR`) and no outside
    region is cut off from the border (a repair can close one); returns the corners, the cells'
    configurations and how many corners were turned.  Corners only ever turn inside (never those
    of the grid's border), so this ends; in the unseen case that it runs out of rounds, the mesh
    is made as it stands and :func:`model.surface.is_closed` says whether it is closed."""
    inside = inside.copy()
    turned = 0
    for _ in range(max_rounds):
        config = configurations(inside)
        fix = REPAIR[config]
        cells = np.argwhere(fix >= 0)
        if not len(cells):
            break
        corner = cells + CORNER_OFFSETS[fix[cells[:, 0], cells[:, 1], cells[:, 2]]]
        inner = np.all((corner > 0) & (corner < np.array(inside.shape) - 1), axis=1)
        if not inner.any():
            break
        corner = corner[inner]
        inside[corner[:, 0], corner[:, 1], corner[:, 2]] = True
        turned += len(np.unique(corner, axis=0))
        inside = fill_cavities(inside)
    return inside, configurations(inside), turned


def contour(grid: Grid, leaves: Leaves, inside: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vertices (V, 3) in cube coordinates, triangles (F, 3) of the surface between the inside
    and outside corners, outward-facing, and the leaf owning each vertex's cell (-1: none)."""
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
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64), np.zeros(0, np.int64)
    rings = np.concatenate(rings)
    cell = _vertex_cells(config.shape, first)
    verts = _place(grid, leaves, cell, np.concatenate(cells), *(np.concatenate(e) for e in zip(*edges)), rings)
    return verts, _triangles(verts, rings), grid.owner[cell[:, 0], cell[:, 1], cell[:, 2]].astype(np.int64)


def _place(grid: Grid, leaves: Leaves, vertex_cell: np.ndarray, cells: np.ndarray, p: np.ndarray,
           axis: np.ndarray, out_first: np.ndarray, rings: np.ndarray) -> np.ndarray:
    """Each vertex at the least-squares point of the leaf planes around its crossing edges (the
    planes of the leaves owning the 4 cells around each edge: one plane inside a leaf, two or
    three where leaves meet at an edge or corner), regularised towards the mean crossing point,
    and kept inside its cell.  An edge with no leaf around it (a surface the sign field closed)
    constrains its vertices to the plane across the edge through its inside corner; and where a
    leaf's plane does not cross the edge it meets (the end of a thin part, a closed gap), its
    point is the inside corner too: such surfaces close at the last inside corner, not further."""
    h = grid.h
    nverts = len(vertex_cell)
    a_pos = grid.corner_positions(p)
    direction = np.eye(3)[axis]
    owners = grid.owner.ravel()[cells]                          # (E, 4) leaf or -1
    free = (owners < 0).all(1)                                   # no leaf around the edge
    normals, consts, points, targets = [], [], [], []
    inner = a_pos + out_first[:, None] * h * direction        # the edge's inside corner
    for k in range(4):
        o = owners[:, k]
        has = o >= 0
        use = has | (free & (k == 0))                           # a free edge constrains once
        o, n_dir, inner_k = o[use], direction[use], inner[use]
        has = has[use]
        n = np.where(has[:, None], leaves.normal[np.maximum(o, 0)], n_dir)
        c = np.where(has, leaves.const[np.maximum(o, 0)], -np.einsum("ij,ij->i", n_dir, inner_k))
        fa = np.einsum("ij,ij->i", n, a_pos[use]) + c            # the plane n.x + c = 0 along the edge
        fb = fa + np.einsum("ij,ij->i", n, n_dir) * h
        crosses = (fa <= 0) != (fb <= 0)
        t = np.where(crosses, fa / np.where(crosses, fa - fb, 1.0), out_first[use].astype(np.float64))
        point = a_pos[use] + t[:, None] * h * n_dir
        for j in range(4):                                      # every vertex around the edge
            normals.append(n)
            consts.append(c)
            points.append(point)
            targets.append(rings[use, j])
    n, c, point, v = (np.concatenate(x) for x in (normals, consts, points, targets))
    prods = n[:, [0, 0, 0, 1, 1, 2]] * n[:, [0, 1, 2, 1, 2, 2]]
    A = np.empty((nverts, 3, 3))
    for k, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        A[:, i, j] = A[:, j, i] = np.bincount(v, prods[:, k], minlength=nverts)
    rhs = np.stack([np.bincount(v, -c * n[:, i], minlength=nverts) for i in range(3)], 1)
    hits = np.maximum(np.bincount(v, minlength=nverts), 1)
    mass = np.stack([np.bincount(v, point[:, i], minlength=nverts) for i in range(3)], 1) / hits[:, None]
    b = rhs - np.einsum("vij,vj->vi", A, mass)
    w, q = np.linalg.eigh(A)                                     # A = q diag(w) q^T
    keep = w > 0.05 * w[:, -1:]
    inv = np.where(keep, 1.0 / np.where(keep, w, 1.0), 0.0)
    x = mass + np.einsum("vij,vj,vkj,vk->vi", q, inv, q, b)
    lo = grid.corner_positions(vertex_cell)
    return np.clip(x, lo, lo + h)


def _vertex_cells(shape: tuple, first: np.ndarray) -> np.ndarray:
    """The (padded) cell index of every vertex."""
    owner = np.repeat(np.arange(len(first) - 1), np.diff(first))
    return np.stack(np.unravel_index(owner, shape), 1)


def _triangles(verts: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Two triangles per quad, split along the diagonal whose triangles' normals agree best."""
    p = verts[quads]
    n1 = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0]), np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 0])
    n2 = np.cross(p[:, 1] - p[:, 0], p[:, 3] - p[:, 0]), np.cross(p[:, 2] - p[:, 1], p[:, 3] - p[:, 1])

    def agree(a, b):
        return np.einsum("ij,ij->i", a, b) / np.maximum(np.linalg.norm(a, axis=1) * np.linalg.norm(b, axis=1), 1e-30)

    first = agree(*n1) >= agree(*n2)
    t = np.where(first[:, None, None],
                 np.stack([quads[:, [0, 1, 2]], quads[:, [0, 2, 3]]], 1),
                 np.stack([quads[:, [0, 1, 3]], quads[:, [1, 2, 3]]], 1))
    return t.reshape(-1, 3)
