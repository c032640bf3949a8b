"""Fewer faces for the closed surface: the finest grid's vertices merged leaf by leaf, so that a
flat leaf becomes one vertex of the mesh (vertex clustering on the octree, as in Schaefer, Ju and
Warren, "Manifold Dual Contouring", 2007).

The contour on the finest grid (:mod:`.dmc`) is closed and 2-manifold.  Each of its vertices
belongs to the leaf owning its cell.  A *cluster* is a set of vertices of one cube of a leaf (at
first the leaf's whole cube) on one side of the leaf's plane and joined by the mesh's own edges;
it is merged into one vertex at its members' mean.  A merge stands only where the mesh stays a
closed 2-manifold (each edge of two faces, wound opposite ways; each vertex's faces one fan; no
two faces on the same vertices; no quad folded onto itself), no face turns over against the fine
faces it comes from, and no member's faces turn away from the leaf's plane.  A cluster that breaks
any of these is split into the octants of its cube and merged again, down to single cells, which
are the fine mesh itself: so the result is closed and manifold wherever the fine mesh is.
Vertices of cells no leaf owns (surfaces the sign field closed) are not merged.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..octree.jit import compiled
from ..octree.parallel import run_parts
from .checks import manifold_faults
from .graph import components
from .grid import Grid, Leaves

FLAT = 0.2
"""The least cosine between a fine face and the plane of a leaf (on its member's side) for the
face's vertices to be merged: a cluster must lie over its plane like a height field."""
FOLD = 0.0
"""The least cosine between a merged face's normal and that of the fine quad it comes from."""
TOLERANCE = 0.3
"""How far (in finest cells) a merged vertex's faces may pass from the fine vertices it stands for."""
MAX_ROUNDS = 12
"""Rounds of halving the failing clusters' cubes; later rounds make them single cells at once."""


@dataclass(frozen=True)
class Clustered:
    """The merged mesh: ``triangles`` index ``vertices`` (wound as the fine mesh), each vertex's
    ``leaf`` (-1: none) and the centre of the cube it stands for (its cell, or its cluster's
    cube), how many fine vertices each stands for (``members``, all >= 1), and the vertex each
    fine vertex became (``label``)."""

    vertices: np.ndarray    # (V, 3)
    triangles: np.ndarray   # (F, 3) int64
    leaf: np.ndarray        # (V,) int64
    centre: np.ndarray      # (V, 3)
    members: np.ndarray     # (V,) int64
    label: np.ndarray       # (fine V,) int64


def quad_normals(verts: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """Unit normals of quads wound counter-clockwise (the cross product of their diagonals)."""
    p = verts[quads]
    n = np.cross(p[:, 2] - p[:, 0], p[:, 3] - p[:, 1])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-30)


def triangulate(verts: np.ndarray, quads: np.ndarray) -> np.ndarray:
    """(2Q, 3): two triangles per quad (consecutive rows), split along the diagonal whose two
    triangles' normals agree best (the cosine of their angle; the first diagonal on a tie)."""
    return _triangulate(np.ascontiguousarray(verts, dtype=np.float64), np.ascontiguousarray(quads, dtype=np.int64))


@compiled
def _triangulate(verts: np.ndarray, quads: np.ndarray) -> np.ndarray:
    out = np.empty((2 * len(quads), 3), np.int64)
    for q in range(len(quads)):
        a, b, c, d = quads[q, 0], quads[q, 1], quads[q, 2], quads[q, 3]
        first = _agree(verts, a, b, c, a, c, d) >= _agree(verts, a, b, d, b, c, d)
        if first:
            out[2 * q, 0], out[2 * q, 1], out[2 * q, 2] = a, b, c
            out[2 * q + 1, 0], out[2 * q + 1, 1], out[2 * q + 1, 2] = a, c, d
        else:
            out[2 * q, 0], out[2 * q, 1], out[2 * q, 2] = a, b, d
            out[2 * q + 1, 0], out[2 * q + 1, 1], out[2 * q + 1, 2] = b, c, d
    return out


@compiled
def _agree(verts, a, b, c, d, e, f) -> float:
    """The cosine between the normals of triangles ``abc`` and ``def`` (0 where one has no area),
    its dot product summed as NumPy's ``einsum`` sums three terms here, (x + z) + y."""
    ux, uy, uz = _normal(verts, a, b, c)
    vx, vy, vz = _normal(verts, d, e, f)
    dot = (ux * vx + uz * vz) + uy * vy
    norms = np.sqrt((ux * ux + uy * uy) + uz * uz) * np.sqrt((vx * vx + vy * vy) + vz * vz)
    return dot / max(norms, 1e-30)


@compiled
def _normal(verts, a, b, c):
    """(b - a) x (c - a), as three scalars."""
    px, py, pz = verts[b, 0] - verts[a, 0], verts[b, 1] - verts[a, 1], verts[b, 2] - verts[a, 2]
    qx, qy, qz = verts[c, 0] - verts[a, 0], verts[c, 1] - verts[a, 1], verts[c, 2] - verts[a, 2]
    return py * qz - pz * qy, pz * qx - px * qz, px * qy - py * qx


def cluster(verts: np.ndarray, quads: np.ndarray, cell: np.ndarray, grid: Grid, leaves: Leaves) -> Clustered:
    """Merge the fine contour's vertices (``verts``, ``quads`` wound outward, ``cell``: each
    vertex's array cell in ``grid``) leaf by leaf as the module docstring says."""
    fine = cell + grid.origin                                     # finest-cell coordinates
    leaf = grid.owner[cell[:, 0], cell[:, 1], cell[:, 2]].astype(np.int64)
    qn = quad_normals(verts, quads)
    front, facing, size = _sides(verts, quads, qn, leaf, leaves)
    edges = np.concatenate([quads[:, [0, 1]], quads[:, [1, 2]], quads[:, [2, 3]], quads[:, [3, 0]]])
    edges = edges[edges[:, 0] < edges[:, 1]]                      # each edge once (it has two quads)
    merged, grow = None, np.zeros(len(verts), bool)
    for rounds in range(1, len(verts) + 1):                      # each round splits at least one cluster
        edges = edges[(size[edges[:, 0]] > 1) & (size[edges[:, 1]] > 1)]   # single cells join nothing
        label = _labels(edges, leaf, size, fine, front)
        merged, bad = _attempt(verts, quads, qn, label, facing, TOLERANCE * grid.h, merged, grow)
        split = bad & (merged.members > 1)
        if not split.any():                                       # a single vertex's fan broken by its neighbours
            split[merged.tris[np.isin(merged.tris, np.flatnonzero(bad)).any(1)].ravel()] = True
            split &= merged.members > 1
            if not split.any():
                break
        grow = split[label]                                       # halve their cubes; after MAX_ROUNDS, single cells
        size[grow] = np.maximum(size[grow] // 2, 1) if rounds < MAX_ROUNDS else 1
    side = size[merged.first]
    centre = ((fine[merged.first] // side[:, None]) * side[:, None] + side[:, None] / 2.0) * grid.h
    return Clustered(merged.pos, merged.tris, leaf[merged.first], centre, merged.members, merged.label)


@dataclass(frozen=True)
class _Merge:
    """One round's clusters merged: each vertex's cluster, each cluster's member count, position
    and a member of it, and the triangles."""

    label: np.ndarray
    members: np.ndarray
    pos: np.ndarray
    first: np.ndarray
    tris: np.ndarray


def _sides(verts: np.ndarray, quads: np.ndarray, qn: np.ndarray, leaf: np.ndarray,
           leaves: Leaves) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Which side of its leaf's plane each vertex's faces look to (True: the normal's), the
    plane's normal on that side, and the cube edge (in cells) each vertex may first be merged
    over: its leaf's, or 1 (not merged) without a leaf or where a face of the vertex turns from
    the plane (:data:`FLAT`)."""
    vn = np.stack([np.bincount(quads.ravel(), np.repeat(qn[:, k], 4), minlength=len(verts)) for k in range(3)], 1)
    plane = leaves.normal[np.maximum(leaf, 0)]
    front = np.einsum("ij,ij->i", vn, plane) >= 0
    facing = plane * np.where(front, 1.0, -1.0)[:, None]
    steep = np.zeros(len(verts), bool)
    for k in range(4):
        np.logical_or.at(steep, quads[:, k], np.einsum("ij,ij->i", qn, facing[quads[:, k]]) < FLAT)
    return front, facing, np.where((leaf >= 0) & ~steep, leaves.cells[np.maximum(leaf, 0)], 1)


def _attempt(verts: np.ndarray, quads: np.ndarray, qn: np.ndarray, label: np.ndarray, facing: np.ndarray,
             tolerance: float, before: _Merge | None, grow: np.ndarray) -> tuple[_Merge, np.ndarray]:
    """The clusters ``label`` merged, and which clusters break a condition of the module
    docstring.  Given the round ``before`` and the vertices whose cubes it halved (``grow``), only
    the clusters that changed and their neighbours are measured again: the others, and everything
    they are measured on, are as they were, and they passed."""
    count = int(label.max()) + 1
    members = np.bincount(label, minlength=count)
    pos = np.stack([np.bincount(label, verts[:, k], minlength=count) for k in range(3)], 1) / members[:, None]
    first = np.full(count, -1, np.int64)
    first[label[::-1]] = np.arange(len(verts))[::-1]
    changed = np.ones(count, bool) if before is None else _changed(label, members, grow, before)
    if before is not None:
        pos[~changed] = before.pos[before.label[first[~changed]]]
    tris, source, folded = _faces(label[quads], pos)
    normal = facing[first]
    measured = changed & (members > 1)
    before_lift, height = _deviation(verts, label, measured, tris, pos, normal)
    pos += height[:, None] * normal                               # the fan up to its members, not below them
    ring = changed.copy()
    ring[tris[_touches(changed, tris)].ravel()] = True
    lifted = np.zeros(count, bool)                                # a vertex of its fan moved
    lifted[tris[_touches(height != 0, tris)].ravel()] = True
    same = measured & ~lifted                                     # measured on the same fan already
    far, _ = _deviation(verts, label, ring & (members > 1) & ~same, tris, pos, normal)
    far[same] = before_lift[same]
    near = _touches(ring, tris)
    bad = _failures(tris[near], source[near], qn, pos, members, ring) | folded | (far > tolerance)
    return _Merge(label, members, pos, first, tris), bad & ring


def _touches(mask: np.ndarray, tris: np.ndarray) -> np.ndarray:
    """(F,) bool: the triangles with a vertex in ``mask``."""
    return mask[tris[:, 0]] | mask[tris[:, 1]] | mask[tris[:, 2]]


def _changed(label: np.ndarray, members: np.ndarray, grow: np.ndarray, before: _Merge) -> np.ndarray:
    """The clusters that are not one of ``before``'s with the same members."""
    return _changed_clusters(label, members, grow, before.label, before.members)


@compiled
def _changed_clusters(label, members, grow, old_label, old_members) -> np.ndarray:
    count, old = len(members), len(old_members)
    low, high = np.full(count, old), np.full(count, -1)
    grown = np.zeros(count, np.bool_)
    for i in range(len(label)):
        c = label[i]
        low[c] = min(low[c], old_label[i])
        high[c] = max(high[c], old_label[i])
        grown[c] |= grow[i]
    out = np.empty(count, np.bool_)
    for c in range(count):
        out[c] = low[c] != high[c] or members[c] != old_members[min(low[c], old - 1)] or grown[c]
    return out


def _labels(edges: np.ndarray, leaf: np.ndarray, size: np.ndarray, fine: np.ndarray, front: np.ndarray) -> np.ndarray:
    """Each vertex's cluster (0, 1, ...): the connected parts, by the mesh's ``edges``, of the
    vertices sharing a leaf, a side of its plane and a cube of their ``size`` in it."""
    block = fine // size[:, None]
    head = (leaf * 2 + front) * 32 + np.log2(size).astype(np.int64)
    bits = int(block.max()).bit_length()
    if int(head.max()).bit_length() + 3 * bits < 63:              # one integer per vertex
        key = ((head << bits | block[:, 0]) << bits | block[:, 1]) << bits | block[:, 2]
    else:
        key = np.unique(np.column_stack([head, block]), axis=0, return_inverse=True)[1].ravel()
    a, b = edges[:, 0], edges[:, 1]
    join = (size[a] > 1) & (key[a] == key[b]) & (leaf[a] >= 0)
    return components(len(leaf), a[join], b[join])


def _deviation(verts: np.ndarray, label: np.ndarray, which: np.ndarray, tris: np.ndarray,
               pos: np.ndarray, normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each cluster of ``which`` (a mask), the largest distance from one of its fine vertices
    to the nearest of the merged triangles around the cluster's vertex, and how far along
    ``normal`` the vertex can move towards its fine vertices where all of them are on one side of
    those triangles (a curved patch's chords pass below or above all of them) without passing
    any (0 where they are on both sides, as on a flat patch, and outside ``which``)."""
    far, height = np.zeros(len(pos)), np.zeros(len(pos))
    corner = tris.ravel()
    keep = which[corner]
    owner, tri = corner[keep], np.repeat(np.arange(len(tris)), 3)[keep]
    fan = np.bincount(owner, minlength=len(pos))
    start = np.cumsum(fan) - fan
    fine = np.flatnonzero(which[label])
    fine = fine[np.argsort(label[fine], kind="stable")]           # each cluster's vertices together
    if not len(fine):
        return far, height
    who = label[fine]
    points, begin, size, fan_tris = verts[fine], start[who], fan[who], tri[np.argsort(owner, kind="stable")]
    dist, offset = np.full(len(fine), np.inf), np.zeros((len(fine), 3))
    run_parts(lambda a, b: _nearest_on_fans(points, begin, size, fan_tris, tris, pos, a, b, dist, offset), len(fine))
    runs = np.flatnonzero(np.r_[True, who[1:] != who[:-1]])
    cluster = who[runs]
    far[cluster] = np.maximum.reduceat(dist, runs)
    up = np.einsum("ij,ij->i", offset, normal[who])
    low, high = np.minimum.reduceat(up, runs), np.maximum.reduceat(up, runs)
    height[cluster] = np.where(np.isfinite(low) & (low > 0), low, np.where(np.isfinite(high) & (high < 0), high, 0.0))
    return far, height


@compiled
def _nearest_on_fans(points, start, count, fan, tris, pos, first, last, dist, offset) -> None:
    """For points ``first:last``, the distance to the nearest of each one's triangles
    ``fan[start:start + count]`` and the vector from that nearest point to it, written into
    ``dist`` (which holds inf) and ``offset``."""
    for i in range(first, last):
        px, py, pz = points[i, 0], points[i, 1], points[i, 2]
        for j in range(start[i], start[i] + count[i]):
            a, b, c = tris[fan[j], 0], tris[fan[j], 1], tris[fan[j], 2]
            qx, qy, qz = _closest_on_triangle(px, py, pz, pos[a, 0], pos[a, 1], pos[a, 2], pos[b, 0], pos[b, 1],
                                              pos[b, 2], pos[c, 0], pos[c, 1], pos[c, 2])
            d = np.sqrt((px - qx) ** 2 + (py - qy) ** 2 + (pz - qz) ** 2)
            if d < dist[i]:
                dist[i] = d
                offset[i, 0], offset[i, 1], offset[i, 2] = px - qx, py - qy, pz - qz


@compiled
def _closest_on_triangle(px, py, pz, ax, ay, az, bx, by, bz, cx, cy, cz):
    """The point of triangle ``abc`` nearest ``p`` (Ericson, "Real-Time Collision Detection",
    5.1.5), as three scalars (every argument a scalar: no array views in the inner loop)."""
    abx, aby, abz = bx - ax, by - ay, bz - az
    acx, acy, acz = cx - ax, cy - ay, cz - az
    d1, d2 = _along(abx, aby, abz, acx, acy, acz, px - ax, py - ay, pz - az)
    if d1 <= 0.0 and d2 <= 0.0:
        return ax, ay, az
    d3, d4 = _along(abx, aby, abz, acx, acy, acz, px - bx, py - by, pz - bz)
    if d3 >= 0.0 and d4 <= d3:
        return bx, by, bz
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        v = d1 / (d1 - d3) if d1 > d3 else 0.0
        return ax + abx * v, ay + aby * v, az + abz * v
    d5, d6 = _along(abx, aby, abz, acx, acy, acz, px - cx, py - cy, pz - cz)
    if d6 >= 0.0 and d5 <= d6:
        return cx, cy, cz
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        w = d2 / (d2 - d6) if d2 > d6 else 0.0
        return ax + acx * w, ay + acy * w, az + acz * w
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and d4 - d3 >= 0.0 and d5 - d6 >= 0.0:
        w = (d4 - d3) / ((d4 - d3) + (d5 - d6)) if (d4 - d3) + (d5 - d6) > 0.0 else 0.0
        return bx + (cx - bx) * w, by + (cy - by) * w, bz + (cz - bz) * w
    total = va + vb + vc
    if total <= 0.0:                                              # no area: its first corner
        return ax, ay, az
    v, w = vb / total, vc / total
    return ax + abx * v + acx * w, ay + aby * v + acy * w, az + abz * v + acz * w


@compiled
def _along(abx, aby, abz, acx, acy, acz, dx, dy, dz):
    """The dot products of ``d`` with the triangle's edges ``ab`` and ``ac``."""
    return abx * dx + aby * dy + abz * dz, acx * dx + acy * dy + acz * dz


def _faces(cq: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The merged quads' triangles, the fine quad each comes from, and which clusters fold a quad
    onto itself (two opposite corners merged, the other two not).  A quad of four clusters gives
    two triangles (:func:`triangulate`), one of three the triangle of its runs' first corners;
    the quads of four first, in order, then those of three."""
    return _merged_faces(np.ascontiguousarray(cq, dtype=np.int64), np.ascontiguousarray(pos, dtype=np.float64))


@compiled
def _merged_faces(cq: np.ndarray, pos: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    q = len(cq)
    kind = np.zeros(q, np.int64)                  # 4: whole, 3: a triangle, 0: dropped, -1: folded
    wholes, threes = 0, 0
    for i in range(q):
        runs = 0
        for k in range(4):
            runs += cq[i, k] != cq[i, (k + 1) % 4]
        if runs == 4:
            kind[i] = -1 if cq[i, 0] == cq[i, 2] or cq[i, 1] == cq[i, 3] else 4
            wholes += kind[i] == 4
        elif runs == 3:
            kind[i] = 3
            threes += 1
    folded = np.zeros(len(pos), np.bool_)
    whole = np.empty((wholes, 4), np.int64)
    tris = np.empty((2 * wholes + threes, 3), np.int64)
    source = np.empty(2 * wholes + threes, np.int64)
    w, t = 0, 2 * wholes
    for i in range(q):
        if kind[i] == -1:
            for k in range(4):
                folded[cq[i, k]] = True
        elif kind[i] == 4:
            whole[w] = cq[i]
            source[2 * w] = source[2 * w + 1] = i
            w += 1
        elif kind[i] == 3:
            m = 0
            for k in range(4):                    # corner k begins a run
                if cq[i, k] != cq[i, (k + 3) % 4]:
                    tris[t, m] = cq[i, k]
                    m += 1
            source[t] = i
            t += 1
    tris[:2 * wholes] = _triangulate(pos, whole)
    return tris, source, folded


def duplicate_faces(tris: np.ndarray, count: int) -> np.ndarray:
    """(F,) bool: the triangles on the same three vertices as another (``count``: more than the
    largest vertex index; the key is made in 64 bits whatever the indices' type)."""
    key = np.sort(tris, axis=1).astype(np.int64)
    key = (key[:, 0] * count + key[:, 1]) * count + key[:, 2]
    order = np.argsort(key)
    same = key[order][1:] == key[order][:-1]
    out = np.zeros(len(tris), bool)
    out[order[1:][same]] = out[order[:-1][same]] = True
    return out


def _failures(tris: np.ndarray, source: np.ndarray, qn: np.ndarray, pos: np.ndarray, members: np.ndarray,
              whole: np.ndarray) -> np.ndarray:
    """(count,) bool: the vertices at which the triangles are not a closed 2-manifold, or whose
    merged triangles (of a vertex standing for several) turn over against their fine quads
    (:data:`FOLD`) or have no area.  ``tris`` holds every triangle of the vertices ``whole``
    (a mask); only edges with an end among them, and their fans, are judged."""
    count = len(members)
    bad = np.zeros(count, bool)
    if not len(tris):
        return bad
    bad[tris[duplicate_faces(tris, count)].ravel()] = True
    # each edge: exactly two faces, one each way
    a, b = tris.ravel(), np.roll(tris, -1, axis=1).ravel()
    wrong, fans = manifold_faults(tris, count)
    wrong &= whole[a] | whole[b]
    bad[a[wrong]] = True
    bad[b[wrong]] = True
    # faces turned over, or without area
    p = pos[tris]
    n = np.cross(p[:, 1] - p[:, 0], p[:, 2] - p[:, 0])
    length = np.linalg.norm(n, axis=1)
    over = np.einsum("ij,ij->i", n, qn[source]) <= FOLD * length
    merged = _touches(members > 1, tris)
    bad[tris[merged & (over | (length <= 0))].ravel()] = True
    return bad | (fans > 1)   # a vertex with a wrong edge is bad already; the others' fans are whole
