"""Geometry of octant patches: plane-cube polygons, distances to them, the probes laid on them,
and the rotations of the up axis (the plane fits are :mod:`.planes`).

Every function works on M octants at once (arrays with a leading M axis, vectorised or compiled) so
that a whole depth of the octree is processed without a Python loop.  Coordinates are local to each octant: the
octant's cube is ``[-h/2, h/2]^3`` around its centre and a plane is ``n . y + d = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .jit import compiled

MAX_POLYGON = 6
"""A plane cuts a cube in a convex polygon of at most 6 vertices."""

_CORNERS = np.array(
    [[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)]
)
_EDGES = np.array(
    [(a, b) for a in range(8) for b in range(a + 1, 8)
     if np.abs(_CORNERS[a] - _CORNERS[b]).sum() == 1.0]
)
_EDGE_START = _CORNERS[_EDGES[:, 0]]
_EDGE_DIR = (_CORNERS[_EDGES[:, 1]] - _CORNERS[_EDGES[:, 0]]).astype(np.float64)


def bounding_box(points: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-axis minimum and maximum of (N, 3) points (reduced along contiguous rows: 5x faster)."""
    t = np.ascontiguousarray(points.T)
    return t.min(1), t.max(1)


def plane_basis(normal: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors (u, v) with ``u x v = n`` spanning each plane (normals (M, 3)): ``u`` is
    ``n`` crossed with the axis along its smallest component (the first of equals), normalised,
    and ``v = n x u``, computed row by row (compiled) as NumPy's ``cross`` and ``linalg.norm``
    compute them (a zero normal gives NaN vectors); float64, whatever the normals' type."""
    normal = np.ascontiguousarray(normal, dtype=np.float64)
    u, v = np.empty_like(normal), np.empty_like(normal)
    _plane_basis(normal, u, v)
    return u, v


@compiled
def _plane_basis(normal: np.ndarray, u: np.ndarray, v: np.ndarray) -> None:
    """:func:`plane_basis` into ``u`` and ``v``."""
    axis = np.empty(3)
    for i in range(len(normal)):
        n0, n1, n2 = normal[i, 0], normal[i, 1], normal[i, 2]
        k = 0
        if abs(n1) < abs(n0):
            k = 1
        if abs(n2) < abs(normal[i, k]):
            k = 2
        axis[:] = 0.0
        axis[k] = 1.0
        a0, a1, a2 = n1 * axis[2] - n2 * axis[1], n2 * axis[0] - n0 * axis[2], n0 * axis[1] - n1 * axis[0]
        norm = np.sqrt((a0 * a0 + a1 * a1) + a2 * a2)
        if norm == 0.0:                              # a zero normal: NaN, as NumPy's 0 / 0 gives
            a0 = a1 = a2 = np.nan
        else:
            a0, a1, a2 = a0 / norm, a1 / norm, a2 / norm
        u[i, 0], u[i, 1], u[i, 2] = a0, a1, a2
        v[i, 0], v[i, 1], v[i, 2] = n1 * a2 - n2 * a1, n2 * a0 - n0 * a2, n0 * a1 - n1 * a0


def cube_polygons(normal: np.ndarray, offset: np.ndarray, size: np.ndarray | float
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Polygons where planes ``n . y + offset = 0`` cut the cubes ``[-size/2, size/2]^3``.

    Returns vertices (M, 6, 3) ordered counter-clockwise about ``n`` (padded by repeating the
    last vertex) and the vertex counts (M,); a count of 0 means the plane misses the cube.
    """
    size = np.ascontiguousarray(np.broadcast_to(np.asarray(size, dtype=np.float64), offset.shape))
    normal = np.ascontiguousarray(normal, dtype=np.float64)
    u, v = plane_basis(normal)
    return _cube_polygons(normal, np.ascontiguousarray(offset, dtype=np.float64), size, u, v, _CORNERS, _EDGES,
                          _EDGE_START, _EDGE_DIR, MAX_POLYGON)


def polygon_distance(points: np.ndarray, normal: np.ndarray, offset: np.ndarray,
                     verts: np.ndarray) -> np.ndarray:
    """Euclidean distance from each point to its own planar convex polygon.

    ``points`` (K, 3), and per point its polygon's plane (normal, offset) and vertices (K, 6, 3)
    as returned by :func:`cube_polygons` (all in the same local frame): the distance to the plane
    and, where the point's foot on it lies outside the polygon (beyond an edge by more than 1e-12
    of the longest edge squared), the distance from the foot to the nearest edge.  Compiled, in
    the order of the NumPy formulation it replaced (``tests/octree/reference_planes.py``).
    """
    out = np.empty(len(points))
    _polygon_distance(np.ascontiguousarray(points, dtype=np.float64), np.ascontiguousarray(normal, dtype=np.float64),
                      np.ascontiguousarray(offset, dtype=np.float64), np.ascontiguousarray(verts, dtype=np.float64),
                      out)
    return out


@compiled
def _polygon_distance(points, normal, offset, verts, out) -> None:
    """:func:`polygon_distance` into ``out``."""
    m = verts.shape[1]
    side = np.empty(m)
    for k in range(len(points)):
        n0, n1, n2 = normal[k, 0], normal[k, 1], normal[k, 2]
        s = 0.0 + points[k, 0] * n0 + points[k, 1] * n1 + points[k, 2] * n2 + offset[k]
        q0, q1, q2 = points[k, 0] - s * n0, points[k, 1] - s * n1, points[k, 2] - s * n2
        longest = 0.0
        dist2 = np.inf
        nan = False
        for i in range(m):
            j = i + 1 if i + 1 < m else 0
            a0, a1, a2 = verts[k, i, 0], verts[k, i, 1], verts[k, i, 2]
            e0, e1, e2 = verts[k, j, 0] - a0, verts[k, j, 1] - a1, verts[k, j, 2] - a2
            r0, r1, r2 = q0 - a0, q1 - a1, q2 - a2
            x0, x1, x2 = e1 * r2 - e2 * r1, e2 * r0 - e0 * r2, e0 * r1 - e1 * r0
            side[i] = x0 * n0 + x1 * n1 + x2 * n2
            ee = e0 * e0 + e1 * e1 + e2 * e2
            if ee != ee or longest != longest:
                longest = np.nan
            elif ee > longest:
                longest = ee
            t = (r0 * e0 + r1 * e1 + r2 * e2) / (ee if ee > 0 else 1.0)
            if t < 0.0:
                t = 0.0
            elif t > 1.0:
                t = 1.0
            d0, d1, d2 = r0 - t * e0, r1 - t * e1, r2 - t * e2
            dd = d0 * d0 + d1 * d1 + d2 * d2
            if dd != dd:
                nan = True
            elif dd < dist2:
                dist2 = dd
        threshold = -1e-12 * longest
        inside = True
        for i in range(m):
            if not side[i] >= threshold:
                inside = False
        outside2 = 0.0 if inside else (np.nan if nan else dist2)
        out[k] = np.sqrt(s * s + outside2)


@dataclass
class PatchProbes:
    """Probes covering M planar patches of octants of one size: a square grid and the boundary.

    Grid probe (i, j) of patch m lies at ``foot[m] + g[i] u[m] + g[j] v[m]`` (in the octant's
    local frame); the grid covers the disc around the octant, and ``grid`` lists the flat indices
    ``(m * k + i) * k + j`` of the points inside the cube, ascending.  Each polygon edge carries
    ``per_edge`` boundary probes ``a + (j / per_edge) (b - a)``, ``j = 0 .. per_edge - 1``.
    Every point of a patch is within about ``spacing / sqrt(2)`` of a probe.  Coordinates are
    made on demand, for the probes that need them.
    """

    u: np.ndarray            # (M, 3) in-plane axes, u x v = n
    v: np.ndarray
    foot: np.ndarray         # (M, 3) foot of the plane from the octant centre
    g: np.ndarray            # (k,) grid coordinates along u and v
    grid: np.ndarray         # (G,) flat indices of the grid probes inside the cube
    edge_a: np.ndarray       # (K, 3) edge start and end points
    edge_b: np.ndarray
    edge_poly: np.ndarray    # (K,) the patch of each edge
    per_edge: int

    @property
    def k(self) -> int:
        return len(self.g)

    @property
    def grid_patch(self) -> np.ndarray:
        return self.grid // (self.k * self.k)

    @property
    def edge_patch(self) -> np.ndarray:
        return np.repeat(self.edge_poly, self.per_edge)

    def grid_uv(self, sel: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """In-plane coordinates (g_i, g_j) of the grid probes ``grid[sel]``."""
        ij = self.grid[sel] % (self.k * self.k)
        return self.g[ij // self.k], self.g[ij % self.k]

    def grid_points(self, sel: np.ndarray) -> np.ndarray:
        """Coordinates (3, len(sel)) of the grid probes ``grid[sel]``."""
        m = self.grid[sel] // (self.k * self.k)
        gi, gj = self.grid_uv(sel)
        # (foot + g_i u) + g_j v, in this order (the rounding of the whole grid's layout)
        return np.stack([self.foot[m, c] + gi * self.u[m, c] + gj * self.v[m, c] for c in range(3)])

    def edge_points(self, sel: np.ndarray) -> np.ndarray:
        """Coordinates (3, len(sel)) of the boundary probes ``sel`` (in edge-by-edge order)."""
        edge, j = np.divmod(sel, self.per_edge)
        t = j / self.per_edge
        a, b = self.edge_a[edge], self.edge_b[edge]
        return np.stack([a[:, c] + t * (b[:, c] - a[:, c]) for c in range(3)])


def patch_probes(normal: np.ndarray, offset: np.ndarray, verts: np.ndarray, count: np.ndarray,
                 size: float, spacing: float) -> PatchProbes:
    """The probes of :class:`PatchProbes` for polygons (``cube_polygons``) in cubes of ``size``."""
    u, v = plane_basis(normal)
    radius = np.sqrt(3.0) / 2.0 * size
    k = int(np.ceil(2.0 * radius / spacing)) + 1
    g = np.linspace(-radius, radius, k)
    foot = -offset[:, None] * normal                                     # (M, 3)
    half = size / 2.0 * (1.0 + 1e-9)
    counts = np.empty(len(normal), np.int64)
    _grid_inside(foot, u, v, g, half, counts, np.empty(0, np.int64))
    grid = np.empty(int(counts.sum()), np.int64)
    _grid_inside(foot, u, v, g, half, counts, grid)
    em, ek = np.nonzero(np.arange(MAX_POLYGON)[None] < count[:, None])
    # edge k runs from vertex k to vertex k + 1, the last one back to vertex 0
    nxt = np.where(ek + 1 < count[em], ek + 1, 0)
    return PatchProbes(u=u, v=v, foot=foot, g=g, grid=grid,
                       edge_a=verts[em, ek], edge_b=verts[em, nxt],
                       edge_poly=em, per_edge=int(np.ceil(np.sqrt(2.0) * size / spacing)))


@compiled
def _grid_inside(foot: np.ndarray, u: np.ndarray, v: np.ndarray, g: np.ndarray, half: float, counts: np.ndarray,
                 grid: np.ndarray) -> None:
    """The grid probes of each patch inside its cube, ``|foot + g_i u + g_j v| <= half`` on every
    axis, the sum taken as ``(foot + g_i u) + g_j v``: with an empty ``grid`` their number per patch
    into ``counts``; else their flat indices ``(m * k + i) * k + j`` (ascending) into ``grid``."""
    k = len(g)
    fill = len(grid) > 0
    w = 0
    for m in range(len(foot)):
        n = 0
        for i in range(k):
            r0 = foot[m, 0] + g[i] * u[m, 0]
            r1 = foot[m, 1] + g[i] * u[m, 1]
            r2 = foot[m, 2] + g[i] * u[m, 2]
            for j in range(k):
                if (abs(r0 + g[j] * v[m, 0]) <= half and abs(r1 + g[j] * v[m, 1]) <= half
                        and abs(r2 + g[j] * v[m, 2]) <= half):
                    if fill:
                        grid[w] = (m * k + i) * k + j
                        w += 1
                    n += 1
        counts[m] = n


def boundary_distance(points: np.ndarray, normal: np.ndarray, size: float) -> np.ndarray:
    """In-plane distance (P,) from probes (rows (3, P), local frame) to their patch's boundary.

    The polygon's edges lie on the cube's faces: in the plane, face i is (h/2 - |y_i|) away
    divided by the sine of the angle between the plane and that face (``normal`` (P, 3)).
    """
    out = None
    for c in range(3):
        dc = (size / 2.0 - np.abs(points[c])) / np.sqrt(np.maximum(1.0 - normal[:, c] ** 2, 1e-12))
        out = dc if out is None else np.minimum(out, dc, out=out)
    return np.maximum(out, 0.0, out=out)


AXES = ("x", "y", "z")
ROTATIONS = 12
"""Classification's rotations about the up axis (paper section 5.1): training draws one per
step, the test-time vote averages over all of them."""


def axis_rotation(angle: float, axis: str = "y") -> np.ndarray:
    """The 3x3 right-handed rotation by ``angle`` radians about ``axis`` (x, y or z)."""
    if axis not in AXES:
        raise ValueError(f"axis must be one of {', '.join(AXES)}, got {axis!r}")
    c, s = np.cos(angle), np.sin(angle)
    a = AXES.index(axis)
    i, j = (a + 1) % 3, (a + 2) % 3
    r = np.eye(3)
    r[i, i], r[i, j], r[j, i], r[j, j] = c, -s, s, c
    return r


def to_y_up(up: str) -> np.ndarray:
    """The 3x3 rotation that turns the axis ``up`` (x, y or z) into +y, the models' up axis: a
    quarter turn about z (x up) or x (z up, the convention of CAD, scanners and ModelNet40), the
    identity for y.  Its entries are exactly 0 and +-1, so points turned and turned back
    (``p @ R.T``, then ``@ R``) are bit-identical."""
    if up not in AXES:
        raise ValueError(f"up must be one of {', '.join(AXES)}, got {up!r}")
    if up == "y":
        return np.eye(3)
    axis, angle = ("z", np.pi / 2) if up == "x" else ("x", -np.pi / 2)
    return np.round(axis_rotation(angle, axis))


def up_rotations(up: str = "y", count: int = ROTATIONS) -> np.ndarray:
    """(count, 3, 3): the rotations by k * 360/count degrees about ``up``, k = 0..count-1."""
    return np.stack([axis_rotation(2 * np.pi * k / count, up) for k in range(count)])


@compiled
def _cube_polygons(normal, offset, size, u, v, corners, edges, edge_start, edge_dir, max_polygon):
    """:func:`cube_polygons` compiled, one plane at a time: the corners on the plane and the edges
    it crosses (tolerance 1e-12 of the cube's side), ordered by their angle about their mean in the
    plane's (u, v) frame (a stable sort: ties in candidate order, corners before edges)."""
    m = len(offset)
    verts = np.empty((m, max_polygon, 3))
    counts = np.zeros(m, np.int64)
    cand = np.empty((20, 3))
    valid = np.empty(20, np.bool_)
    f = np.empty(8)
    idx = np.empty(20, np.int64)
    ang = np.empty(20)
    for i in range(m):
        s = size[i]
        tol = 1e-12 * s
        for c in range(8):
            f[c] = (corners[c, 0] * normal[i, 0] + corners[c, 1] * normal[i, 1] + corners[c, 2] * normal[i, 2]) * s \
                + offset[i]
            valid[c] = abs(f[c]) <= tol
            for a in range(3):
                cand[c, a] = corners[c, a] * s
        for e in range(12):
            fa, fb = f[edges[e, 0]], f[edges[e, 1]]
            cross = (fa > tol and fb < -tol) or (fa < -tol and fb > tol)
            t = fa / (fa - fb) if cross else fa
            valid[8 + e] = cross
            for a in range(3):
                cand[8 + e, a] = (edge_start[e, a] + t * edge_dir[e, a]) * s
        count = 0
        mean = np.zeros(3)
        for j in range(20):
            if valid[j]:
                idx[count] = j
                count += 1
                for a in range(3):
                    mean[a] += cand[j, a]
        if count == 0:
            for j in range(max_polygon):
                verts[i, j] = cand[0]
            continue
        for a in range(3):
            mean[a] /= count
        for r in range(count):
            j = idx[r]
            au = av = 0.0
            for a in range(3):
                rel = cand[j, a] - mean[a]
                au += rel * u[i, a]
                av += rel * v[i, a]
            ang[r] = np.arctan2(av, au)
        for r in range(1, count):                       # stable insertion sort by angle
            aj, ij = ang[r], idx[r]
            q = r
            while q > 0 and ang[q - 1] > aj:
                ang[q], idx[q] = ang[q - 1], idx[q - 1]
                q -= 1
            ang[q], idx[q] = aj, ij
        kept = min(count, max_polygon)
        counts[i] = kept
        for r in range(max_polygon):
            verts[i, r] = cand[idx[min(r, kept - 1)]]
    return verts, counts
