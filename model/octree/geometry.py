"""Vectorised geometry of octant patches: plane fits, plane-cube polygons and distances.

Every function works on M octants at once (arrays with a leading M axis) so that a whole depth
of the octree is processed without a Python loop.  Coordinates are local to each octant: the
octant's cube is ``[-h/2, h/2]^3`` around its centre and a plane is ``n . y + d = 0``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .jit import compiled, inlined

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


def smallest_eigenvectors(c: np.ndarray, refine: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Unit eigenvectors (M, 3) of the smallest eigenvalues of symmetric 3x3 matrices given by
    components ``c`` (6, M): xx, xy, xz, yy, yz, zz; and their eigenvalues (3, M), descending.

    Closed form (the trigonometric method), then the null space of ``C - lambda I`` as the best of
    its three row crosses (where that space has more than one dimension the vector is arbitrary
    but unit length).  ``refine``: the closed-form eigenvalues carry sqrt(eps) relative error near
    a double root; one Rayleigh-quotient step makes the smallest one accurate before its vector is
    taken again.  Compiled, row by row, in the order of the NumPy formulation it replaced
    (``tests/octree/reference_planes.py``: the same bits); the arc cosine and cosines are NumPy's.
    """
    c = np.ascontiguousarray(c, dtype=np.float64)
    m = c.shape[1]
    q, p, arg = np.empty(m), np.empty(m), np.empty(m)
    _eigen_angle(c, q, p, arg)
    phi = np.arccos(arg) / 3.0
    values, vectors = np.empty((3, m)), np.empty((m, 3))
    _eigen_vectors(c, q, p, np.cos(phi), np.cos(phi + 2.0 * np.pi / 3.0), refine, values, vectors)
    return vectors, values


@compiled
def _eigen_angle(c: np.ndarray, q: np.ndarray, p: np.ndarray, arg: np.ndarray) -> None:
    """Per matrix, :func:`_angle` into ``q``, ``p`` and ``arg``."""
    for i in range(c.shape[1]):
        q[i], p[i], arg[i] = _angle(c[0, i], c[1, i], c[2, i], c[3, i], c[4, i], c[5, i])


@inlined
def _angle(xx: float, xy: float, xz: float, yy: float, yz: float, zz: float) -> tuple[float, float, float]:
    """The trigonometric method's mean eigenvalue ``q``, spread ``p`` and the cosine of three times
    its angle (clipped to [-1, 1])."""
    q = (xx + yy + zz) / 3.0
    p1 = xy * xy + xz * xz + yz * yz
    dx, dy, dz = xx - q, yy - q, zz - q
    p = np.sqrt((dx * dx + dy * dy + dz * dz + 2.0 * p1) / 6.0)
    inv = 1.0 / (p if p > 0 else 1.0)
    dx, dy, dz = dx * inv, dy * inv, dz * inv
    bxy, bxz, byz = xy * inv, xz * inv, yz * inv
    det = dx * (dy * dz - byz * byz) - bxy * (bxy * dz - byz * bxz) + bxz * (bxy * byz - dy * bxz)
    a = det * 0.5
    if a > 1.0:
        a = 1.0
    elif a < -1.0:
        a = -1.0
    return q, p, a


@inlined
def _nan_max(a: float, b: float) -> float:
    """``np.maximum``: NaN if either is NaN."""
    if a != a or b != b:
        return np.nan
    return a if a >= b else b


@inlined
def _null_vector(xx: float, xy: float, xz: float, yy: float, yz: float, zz: float, lam: float,
                 out: np.ndarray, i: int) -> None:
    """Row ``i`` of ``out``: the unit null vector of ``C - lam I`` (the best of three row crosses)."""
    ax, by, cz = xx - lam, yy - lam, zz - lam
    a0, a1, a2 = xy * yz - xz * by, xz * xy - ax * yz, ax * by - xy * xy
    b0, b1, b2 = xy * cz - xz * yz, xz * xz - ax * cz, ax * yz - xy * xz
    c0, c1, c2 = by * cz - yz * yz, yz * xz - xy * cz, xy * yz - by * xz
    n01 = a0 * a0 + a1 * a1 + a2 * a2
    n02 = b0 * b0 + b1 * b1 + b2 * b2
    n12 = c0 * c0 + c1 * c1 + c2 * c2
    if n01 >= n02:
        best = 0 if n01 >= n12 else 2
    else:
        best = 1 if n02 >= n12 else 2
    if best == 0:
        v0, v1, v2 = a0, a1, a2
    elif best == 1:
        v0, v1, v2 = b0, b1, b2
    else:
        v0, v1, v2 = c0, c1, c2
    n = np.sqrt(_nan_max(_nan_max(n01, n02), n12))
    if n > 0:
        out[i, 0], out[i, 1], out[i, 2] = v0 / n, v1 / n, v2 / n
    else:
        out[i, 0], out[i, 1], out[i, 2] = 1.0, v1 / 1.0, v2 / 1.0


@compiled
def _eigen_vectors(c: np.ndarray, q: np.ndarray, p: np.ndarray, cos1: np.ndarray, cos3: np.ndarray,
                   refine: bool, values: np.ndarray, vectors: np.ndarray) -> None:
    """Per matrix, :func:`_eigen` into ``values`` (3, M) and ``vectors`` (M, 3)."""
    for i in range(c.shape[1]):
        values[0, i], values[1, i], values[2, i] = _eigen(c[0, i], c[1, i], c[2, i], c[3, i], c[4, i], c[5, i],
                                                          q[i], p[i], cos1[i], cos3[i], refine, vectors, i)


@inlined
def _eigen(xx: float, xy: float, xz: float, yy: float, yz: float, zz: float, q: float, p: float, cos1: float,
           cos3: float, refine: bool, vectors: np.ndarray, i: int) -> tuple[float, float, float]:
    """The eigenvalues, descending, from :func:`_angle`'s parts and the cosines of the largest's
    and the smallest's angle; the smallest's vector into row ``i`` of ``vectors``, refined by a
    Rayleigh step."""
    e1 = q + 2.0 * p * cos1
    e3 = q + 2.0 * p * cos3
    _null_vector(xx, xy, xz, yy, yz, zz, e3, vectors, i)
    if refine:
        x, y, z = vectors[i, 0], vectors[i, 1], vectors[i, 2]
        lam = xx * x * x + yy * y * y + zz * z * z + 2.0 * (xy * x * y + xz * x * z + yz * y * z)
        _null_vector(xx, xy, xz, yy, yz, zz, lam, vectors, i)
    return e1, 3.0 * q - e1 - e3, e3


def fit_planes(count: np.ndarray, s1: np.ndarray, s2: np.ndarray, nsum: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares planes (paper eq. 1) from point moments; normals oriented by ``nsum``.

    ``count`` (M,), ``s1`` (3, M) sums of points, ``s2`` (6, M) sums of products xx, xy, xz,
    yy, yz, zz, ``nsum`` (3, M) sums of input normals.  Returns unit normals (M, 3), centroids
    (M, 3) and a mask of degenerate fits (a single point or collinear points), whose normal is
    the average input normal made orthogonal to the points' line (every count at least 1, else
    ValueError).  Three or more points: the
    smallest eigenvector of their covariance, refined by a Rayleigh step
    (:func:`smallest_eigenvectors`); a spread along the second axis below ~0.03% of the first is a
    line (or a point), no plane.  Compiled, node by node, in the order of the NumPy formulation it
    replaced (``tests/octree/reference_planes.py``: the same bits).
    """
    count = np.ascontiguousarray(count)
    if len(count) and count.min() < 1:
        raise ValueError(f"every plane needs at least one point, got a count of {count.min()}")
    m = len(count)
    centroid, cov = np.empty((m, 3)), np.empty((6, m))
    q, p, arg = np.empty(m), np.empty(m), np.empty(m)
    _moment_covariances(count, s1, s2, centroid, cov, q, p, arg)
    phi = np.arccos(arg) / 3.0
    normal, degenerate, bad = np.empty((m, 3)), np.empty(m, np.bool_), np.zeros(m, np.bool_)
    _plane_normals(count, cov, nsum, q, p, np.cos(phi), np.cos(phi + 2.0 * np.pi / 3.0), normal, degenerate, bad)
    if bad.any():             # the average normal vanishes or lies along the line: any direction across it
        rows = np.flatnonzero(bad)
        normal[rows] = _across(cov[:, rows])
        flip = (normal[rows] * nsum[:, rows].T).sum(1) < 0
        normal[rows[flip]] *= -1.0
    return normal, centroid, degenerate


@compiled
def _moment_covariances(count, s1, s2, centroid, cov, q, p, arg) -> None:
    """Centroids (M, 3) and covariances (6, M) from the moments; for nodes of three or more
    points the trigonometric method's parts (:func:`_eigen_angle`) into ``q``, ``p``, ``arg``
    (elsewhere arg = 1)."""
    for i in range(len(count)):
        n = count[i]
        m0, m1, m2 = s1[0, i] / n, s1[1, i] / n, s1[2, i] / n
        centroid[i, 0], centroid[i, 1], centroid[i, 2] = m0, m1, m2
        cov[0, i] = s2[0, i] / n - m0 * m0
        cov[1, i] = s2[1, i] / n - m0 * m1
        cov[2, i] = s2[2, i] / n - m0 * m2
        cov[3, i] = s2[3, i] / n - m1 * m1
        cov[4, i] = s2[4, i] / n - m1 * m2
        cov[5, i] = s2[5, i] / n - m2 * m2
        q[i], p[i], arg[i] = 0.0, 0.0, 1.0
        if n >= 3:
            q[i], p[i], arg[i] = _angle(cov[0, i], cov[1, i], cov[2, i], cov[3, i], cov[4, i], cov[5, i])


@inlined
def _unit(a0: float, a1: float, a2: float, floor: float) -> tuple[float, float, float]:
    """``a / np.maximum(np.sqrt((a * a).sum(0)), floor)``."""
    n = _nan_max(np.sqrt(a0 * a0 + a1 * a1 + a2 * a2), floor)
    return a0 / n, a1 / n, a2 / n


@compiled
def _plane_normals(count, cov, nsum, q, p, cos1, cos3, normal, degenerate, bad) -> None:
    """Each node's oriented normal (M, 3) and whether its fit is degenerate; ``bad``: a degenerate
    node whose average normal vanishes (or lies along its line), left to :func:`_across`."""
    for i in range(len(count)):
        n0 = n1 = n2 = 0.0
        degenerate[i] = count[i] < 3
        if not degenerate[i]:
            e1, e2, _ = _eigen(cov[0, i], cov[1, i], cov[2, i], cov[3, i], cov[4, i], cov[5, i], q[i], p[i],
                               cos1[i], cos3[i], True, normal, i)
            degenerate[i] = (e2 <= 1e-7 * e1) or (e1 <= 0)
            n0, n1, n2 = normal[i, 0], normal[i, 1], normal[i, 2]
        single = False
        if count[i] == 1:
            a0, a1, a2 = _unit(nsum[0, i], nsum[1, i], nsum[2, i], 1e-300)
            an = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
            if an > 1e-12:
                n0, n1, n2 = a0 / an, a1 / an, a2 / an
                single = True
        if degenerate[i] and not single:
            ok, n0, n1, n2 = _line_normal(cov[0, i], cov[1, i], cov[2, i], cov[3, i], cov[4, i], cov[5, i],
                                          nsum[0, i], nsum[1, i], nsum[2, i])
            bad[i] = not ok
        if n0 * nsum[0, i] + n1 * nsum[1, i] + n2 * nsum[2, i] < 0:
            n0, n1, n2 = -n0, -n1, -n2
        normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2


@inlined
def _line_normal(xx, xy, xz, yy, yz, zz, s0, s1, s2) -> tuple[bool, float, float, float]:
    """A normal for points on a line (or one point): the average normal ``s`` minus its part along
    the line.  For collinear points the covariance is ``s^2 u u^T``, so its column with the largest
    diagonal entry points along the line ``u`` (coordinates are in the unit cube: 1e-20 is far
    below any octant's size squared, so smaller spreads count as a single point).  False where
    that leaves no direction (the average normal vanishes or lies along the line)."""
    use_y = yy > xx
    use_z = zz > _nan_max(xx, yy)
    if use_z:
        u0, u1, u2 = xz, yz, zz
    elif use_y:
        u0, u1, u2 = xy, yy, yz
    else:
        u0, u1, u2 = xx, xy, xz
    un = np.sqrt(u0 * u0 + u1 * u1 + u2 * u2)
    line = (_nan_max(_nan_max(xx, yy), zz) > 1e-20) and (un > 0)
    d = un if un > 0 else 1.0
    u0, u1, u2 = u0 / d, u1 / d, u2 / d
    a0, a1, a2 = _unit(s0, s1, s2, 1e-300)
    w = 0.0 + a0 * u0 + a1 * u1 + a2 * u2 if line else 0.0       # NumPy's sum starts at +0.0
    a0, a1, a2 = a0 - w * u0, a1 - w * u1, a2 - w * u2
    an = np.sqrt(a0 * a0 + a1 * a1 + a2 * a2)
    ok = an > 1e-12
    d = an if ok else 1.0
    return ok, a0 / d, a1 / d, a2 / d


def _across(cov: np.ndarray) -> np.ndarray:
    """Unit vectors (M, 3) across each line of collinear points (``cov`` (6, M)), or along z where
    there is no line: where the average normal leaves no direction (:func:`_line_normal`)."""
    xx, xy, xz, yy, yz, zz = cov
    use_y = yy > xx
    use_z = zz > np.maximum(xx, yy)
    u = np.stack([np.where(use_z, xz, np.where(use_y, xy, xx)),
                  np.where(use_z, yz, np.where(use_y, yy, xy)),
                  np.where(use_z, zz, np.where(use_y, yz, xz))])
    un = np.sqrt((u * u).sum(0))
    line = (np.maximum(np.maximum(xx, yy), zz) > 1e-20) & (un > 0)
    u /= np.where(un > 0, un, 1.0)
    ub = np.where(line, u, [[0.0], [0.0], [1.0]]).T
    helper = np.where(np.abs(ub[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
    perp = np.cross(ub, helper)
    return perp / np.linalg.norm(perp, axis=1, keepdims=True)


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
