"""Faces that cross other faces: a mesh closed in its index buffer and as a welding reader loads
it can still pass through itself, and then it is not the boundary of a solid (a slicer, a boolean
or a volume computation goes wrong there).

The rule follows MeshLab's self-intersection selection (``compute_selection_by_self_
intersections_per_face``, vcg's ``Clean::SelfIntersections``), in double precision and with
touching counted: two faces on no common vertex cross where the triangles share any point
(Moeller's interval test, and the coplanar case in the plane they share), so a vertex lying on
another face counts; two faces on one common vertex cross where the edge of either opposite that
vertex meets the other triangle; two faces on the same three vertices cross; faces on two common
vertices (neighbours across an edge) do not count, nor does a triangle without area (its
vertices' cross product exactly zero).  On 56 closed surfaces (13 decoded outputs and 15
real-mesh octrees at depths 6-8, merged and not) it marks 99.8% of the faces MeshLab marks and
15% more faces in all: faces that only touch, which MeshLab, in single precision and testing a
shared vertex's faces on a shortened segment, lets pass.  Coordinates are scaled by a power of
two to below 1 (exactly) so that the interval test's products neither overflow nor underflow;
where they would still underflow (triangles coplanar to 1e-90) the test divides instead.
Candidate pairs come from a hashed uniform grid over the faces' bounding boxes, each pair
tested once (in the cell that holds the lower corner of the boxes' overlap); the few faces much
larger than the grid's cell are tested against every face whose box they meet.
"""

from __future__ import annotations

import numpy as np

from ..octree.jit import compiled


def crossing_faces(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """(F,) bool: the faces that cross another face of the mesh (the module's rule).  Vertices
    must be finite (ValueError otherwise)."""
    faces = np.ascontiguousarray(faces, dtype=np.int64)
    out = np.zeros(len(faces), bool)
    if len(faces) < 2:
        return out
    v = np.asarray(vertices, dtype=np.float64)
    corners = v[faces]
    if not np.isfinite(corners).all():
        raise ValueError("crossing_faces needs finite vertex positions")
    top = float(np.abs(corners).max())
    scale = 2.0 ** -np.frexp(top)[1] if top > 0 else 1.0          # exact: |x| < 1, no overflow
    v = np.ascontiguousarray(v * scale)
    lo, hi = corners.min(1) * scale, corners.max(1) * scale      # each face's box (scaled exactly)
    cell = max(2.0 * float(np.median(np.max(hi - lo, axis=1))), 2.0 ** -40)
    while True:                                                   # a few large faces are tested on their own
        first, last = np.floor(lo / cell).astype(np.int64), np.floor(hi / cell).astype(np.int64)
        large = (last - first).max(1) >= LARGE
        if large.sum() <= max(LARGE_FACES, int(np.sqrt(len(faces)))):
            break
        cell *= 2.0
    order = np.argsort(lo[:, 0], kind="stable")                 # each cell's faces by their lowest x
    _grid_pairs(v, faces, lo, hi, first, last, large, order, out)
    _large_pairs(v, faces, lo, hi, np.flatnonzero(large), out)
    return out


LARGE = 4
"""A face whose box spans this many grid cells more than one along an axis is tested against
every face whose box it meets, not through the grid (so a few huge faces do not fill it)."""
LARGE_FACES = 64
"""The most such faces (or the square root of the face count) before the grid is made coarser."""


@compiled
def _grid_pairs(v, faces, lo, hi, first, last, large, order, out) -> None:
    """Every pair of the grid's faces (not ``large``) whose boxes share a cell, tested once; ``out``
    marks both faces of a crossing pair.  The (face, cell) entries are bucketed by a hash of the
    cell (counting sort), in each bucket by the faces' lowest x (``order``), so a face's partners
    end where they start beyond its box."""
    total = 0
    for f in range(len(faces)):
        if not large[f]:
            total += (last[f, 0] - first[f, 0] + 1) * (last[f, 1] - first[f, 1] + 1) * (last[f, 2] - first[f, 2] + 1)
    buckets = 1
    while buckets < total:
        buckets *= 2
    start = np.zeros(buckets + 1, np.int64)
    for f in range(len(faces)):
        if not large[f]:
            for x in range(first[f, 0], last[f, 0] + 1):
                for y in range(first[f, 1], last[f, 1] + 1):
                    for z in range(first[f, 2], last[f, 2] + 1):
                        start[_bucket(x, y, z, buckets) + 1] += 1
    for b in range(buckets):
        start[b + 1] += start[b]
    fill = start[:-1].copy()
    entry = np.empty(total, np.int64)
    cells = np.empty((total, 3), np.int64)
    for f in order:
        if not large[f]:
            for x in range(first[f, 0], last[f, 0] + 1):
                for y in range(first[f, 1], last[f, 1] + 1):
                    for z in range(first[f, 2], last[f, 2] + 1):
                        b = _bucket(x, y, z, buckets)
                        entry[fill[b]] = f
                        cells[fill[b], 0], cells[fill[b], 1], cells[fill[b], 2] = x, y, z
                        fill[b] += 1
    for b in range(buckets):
        for i in range(start[b], start[b + 1]):
            f = entry[i]
            for j in range(i + 1, start[b + 1]):
                g = entry[j]
                if lo[g, 0] > hi[f, 0]:
                    break
                if cells[j, 0] != cells[i, 0] or cells[j, 1] != cells[i, 1] or cells[j, 2] != cells[i, 2]:
                    continue
                if not _owns_pair(f, g, lo, hi, first, cells[i, 0], cells[i, 1], cells[i, 2]):
                    continue
                if (out[f] and out[g]) or not _faces_cross(v, faces, f, g):
                    continue
                out[f] = True
                out[g] = True


@compiled
def _bucket(x: int, y: int, z: int, buckets: int) -> int:
    h = (x * 73856093) ^ (y * 19349663) ^ (z * 83492791)
    h ^= h >> 17
    return h & (buckets - 1)


@compiled
def _large_pairs(v, faces, lo, hi, large, out) -> None:
    """Each large face against every other face whose box its box meets (a pair of large faces once)."""
    is_large = np.zeros(len(faces), np.bool_)
    for f in large:
        is_large[f] = True
    for f in large:
        for g in range(len(faces)):
            if g == f or (is_large[g] and g < f):
                continue
            meet = True
            for k in range(3):
                if lo[f, k] > hi[g, k] or lo[g, k] > hi[f, k]:
                    meet = False
            if meet and not (out[f] and out[g]) and _faces_cross(v, faces, f, g):
                out[f] = True
                out[g] = True


@compiled
def _owns_pair(f, g, lo, hi, first, x, y, z) -> bool:
    """The boxes of ``f`` and ``g`` overlap and cell (x, y, z) holds the lower corner of their
    overlap (so the pair is tested in one cell only)."""
    for k in range(3):
        if lo[f, k] > hi[g, k] or lo[g, k] > hi[f, k]:
            return False
    return max(first[f, 0], first[g, 0]) == x and max(first[f, 1], first[g, 1]) == y \
        and max(first[f, 2], first[g, 2]) == z


@compiled
def _faces_cross(v, faces, f, g) -> bool:
    """Faces ``f`` and ``g`` cross by the module's rule (their common vertices decide the test)."""
    p0, p1, p2 = v[faces[f, 0]], v[faces[f, 1]], v[faces[f, 2]]
    q0, q1, q2 = v[faces[g, 0]], v[faces[g, 1]], v[faces[g, 2]]
    n1, n2 = _normal(p0, p1, p2), _normal(q0, q1, q2)
    if _is_zero(n1) or _is_zero(n2):                              # no area: never counts
        return False
    shared = 0
    sf, sg = -1, -1
    for a in range(3):                                            # distinct indices: a face has area
        for b in range(3):
            if faces[f, a] == faces[g, b]:
                shared += 1
                sf, sg = a, b
    if shared == 3:
        return True
    if shared == 2:
        return False
    if shared == 0:
        return _triangles_meet(p0, p1, p2, n1, q0, q1, q2, n2)
    return _segment_meets(v[faces[f, (sf + 1) % 3]], v[faces[f, (sf + 2) % 3]], q0, q1, q2) or \
        _segment_meets(v[faces[g, (sg + 1) % 3]], v[faces[g, (sg + 2) % 3]], p0, p1, p2)


@compiled
def _sub(a, b):
    return a[0] - b[0], a[1] - b[1], a[2] - b[2]


@compiled
def _cross3(ax, ay, az, bx, by, bz):
    return ay * bz - az * by, az * bx - ax * bz, ax * by - ay * bx


@compiled
def _segment_meets(s0, s1, a, b, c) -> bool:
    """The closed segment ``s0 s1`` meets triangle ``abc`` (Moeller-Trumbore; a segment in the
    triangle's plane does not count)."""
    e1x, e1y, e1z = _sub(b, a)
    e2x, e2y, e2z = _sub(c, a)
    dx, dy, dz = _sub(s1, s0)
    px, py, pz = _cross3(dx, dy, dz, e2x, e2y, e2z)
    det = e1x * px + e1y * py + e1z * pz
    if det == 0.0:
        return False
    tx, ty, tz = _sub(s0, a)
    u = (tx * px + ty * py + tz * pz) / det
    if u < 0.0 or u > 1.0:
        return False
    qx, qy, qz = _cross3(tx, ty, tz, e1x, e1y, e1z)
    w = (dx * qx + dy * qy + dz * qz) / det
    if w < 0.0 or u + w > 1.0:
        return False
    t = (e2x * qx + e2y * qy + e2z * qz) / det
    return 0.0 <= t <= 1.0


@compiled
def _triangles_meet(v0, v1, v2, n1, u0, u1, u2, n2) -> bool:
    """Triangles ``v`` and ``u``, with area and normals ``n1`` and ``n2`` (:func:`_normal`), share a
    point (Moeller, "A fast triangle-triangle intersection test", 1997, without divisions;
    coplanar triangles tested in their plane)."""
    d1 = -_dot(n1, v0)
    du0, du1, du2 = _dot(n1, u0) + d1, _dot(n1, u1) + d1, _dot(n1, u2) + d1
    if du0 * du1 > 0.0 and du0 * du2 > 0.0:
        return False
    d2 = -_dot(n2, u0)
    dv0, dv1, dv2 = _dot(n2, v0) + d2, _dot(n2, v1) + d2, _dot(n2, v2) + d2
    if dv0 * dv1 > 0.0 and dv0 * dv2 > 0.0:
        return False
    if dv0 == 0.0 and dv1 == 0.0 and dv2 == 0.0:
        return _coplanar_meet(n1, v0, v1, v2, u0, u1, u2)
    dx, dy, dz = _cross3(n1[0], n1[1], n1[2], n2[0], n2[1], n2[2])
    axis = 0
    if abs(dy) > abs(dx):
        axis = 1
    if abs(dz) > max(abs(dx), abs(dy)):
        axis = 2
    ok1, a, b, c, x0, x1 = _interval(v0[axis], v1[axis], v2[axis], dv0, dv1, dv2)
    ok2, d, e, f, y0, y1 = _interval(u0[axis], u1[axis], u2[axis], du0, du1, du2)
    if not ok1 or not ok2:
        return _coplanar_meet(n1, v0, v1, v2, u0, u1, u2)
    xx, yy = x0 * x1, y0 * y1
    xxyy = xx * yy
    if xxyy == 0.0 or not np.isfinite(xxyy):                      # products out of range: divide
        s0, s1, t0, t1 = a + b / x0, a + c / x1, d + e / y0, d + f / y1
    else:
        s0, s1 = a * xxyy + b * x1 * yy, a * xxyy + c * x0 * yy
        t0, t1 = d * xxyy + e * xx * y1, d * xxyy + f * xx * y0
    return not (max(s0, s1) < min(t0, t1) or max(t0, t1) < min(s0, s1))


@compiled
def _interval(p0, p1, p2, d0, d1, d2):
    """Moeller's NEWCOMPUTE_INTERVALS: (found, a, b, c, x0, x1), the interval on the planes' common
    line as fractions without division; found is False for a triangle in the other's plane."""
    if d0 * d1 > 0.0:
        return True, p2, (p0 - p2) * d2, (p1 - p2) * d2, d2 - d0, d2 - d1
    if d0 * d2 > 0.0:
        return True, p1, (p0 - p1) * d1, (p2 - p1) * d1, d1 - d0, d1 - d2
    if d1 * d2 > 0.0 or d0 != 0.0:
        return True, p0, (p1 - p0) * d0, (p2 - p0) * d0, d0 - d1, d0 - d2
    if d1 != 0.0:
        return True, p1, (p0 - p1) * d1, (p2 - p1) * d1, d1 - d0, d1 - d2
    if d2 != 0.0:
        return True, p2, (p0 - p2) * d2, (p1 - p2) * d2, d2 - d0, d2 - d1
    return False, 0.0, 0.0, 0.0, 0.0, 0.0


@compiled
def _normal(a, b, c):
    ux, uy, uz = _sub(b, a)
    wx, wy, wz = _sub(c, a)
    return _cross3(ux, uy, uz, wx, wy, wz)


@compiled
def _is_zero(n) -> bool:
    return n[0] == 0.0 and n[1] == 0.0 and n[2] == 0.0


@compiled
def _dot(n, p) -> float:
    return n[0] * p[0] + n[1] * p[1] + n[2] * p[2]


@compiled
def _coplanar_meet(n, v0, v1, v2, u0, u1, u2) -> bool:
    """Coplanar triangles meet: projected on the axis plane where ``n`` is largest, an edge of one
    crosses an edge of the other, or one holds a vertex of the other."""
    ax, ay, az = abs(n[0]), abs(n[1]), abs(n[2])
    i, j = 1, 2                                                   # drop x
    if ay > ax and ay >= az:
        i, j = 0, 2
    elif az > ax and az > ay:
        i, j = 0, 1
    p = ((v0[i], v0[j]), (v1[i], v1[j]), (v2[i], v2[j]))
    q = ((u0[i], u0[j]), (u1[i], u1[j]), (u2[i], u2[j]))
    for a in range(3):
        for b in range(3):
            if _segments_meet_2d(p[a], p[(a + 1) % 3], q[b], q[(b + 1) % 3]):
                return True
    return _inside_2d(p[0], q[0], q[1], q[2]) or _inside_2d(q[0], p[0], p[1], p[2])


@compiled
def _orient_2d(a, b, c) -> float:
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


@compiled
def _segments_meet_2d(a, b, c, d) -> bool:
    o1, o2 = _orient_2d(a, b, c), _orient_2d(a, b, d)
    o3, o4 = _orient_2d(c, d, a), _orient_2d(c, d, b)
    if o1 * o2 > 0.0 or o3 * o4 > 0.0:
        return False
    if o1 == 0.0 and o2 == 0.0:                                   # collinear: overlapping spans
        for k in range(2):
            if max(a[k], b[k]) < min(c[k], d[k]) or max(c[k], d[k]) < min(a[k], b[k]):
                return False
    return True


@compiled
def _inside_2d(p, a, b, c) -> bool:
    o1, o2, o3 = _orient_2d(a, b, p), _orient_2d(b, c, p), _orient_2d(c, a, p)
    return (o1 >= 0.0 and o2 >= 0.0 and o3 >= 0.0) or (o1 <= 0.0 and o2 <= 0.0 and o3 <= 0.0)
