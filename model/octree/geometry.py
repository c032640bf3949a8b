"""Vectorised geometry of octant patches: plane fits, plane-cube polygons and distances.

Every function works on M octants at once (arrays with a leading M axis) so that a whole depth
of the octree is processed without a Python loop.  Coordinates are local to each octant: the
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


def symmetric_eigen(c: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Eigenvalues (3, M) in descending order of symmetric 3x3 matrices given by components.

    ``c`` is (6, M): xx, xy, xz, yy, yz, zz.  Closed form (trigonometric method) on contiguous
    rows, several times faster than ``np.linalg.eigh`` on many small matrices.
    """
    xx, xy, xz, yy, yz, zz = c
    q = (xx + yy + zz) / 3.0
    p1 = xy * xy + xz * xz + yz * yz
    dx, dy, dz = xx - q, yy - q, zz - q
    p = np.sqrt((dx * dx + dy * dy + dz * dz + 2.0 * p1) / 6.0)
    inv = 1.0 / np.where(p > 0, p, 1.0)
    dx, dy, dz = dx * inv, dy * inv, dz * inv
    bxy, bxz, byz = xy * inv, xz * inv, yz * inv
    det = dx * (dy * dz - byz * byz) - bxy * (bxy * dz - byz * bxz) + bxz * (bxy * byz - dy * bxz)
    phi = np.arccos(np.clip(det * 0.5, -1.0, 1.0)) / 3.0
    e1 = q + 2.0 * p * np.cos(phi)
    e3 = q + 2.0 * p * np.cos(phi + 2.0 * np.pi / 3.0)
    return np.stack([e1, 3.0 * q - e1 - e3, e3])


def eigenvector(c: np.ndarray, lam: np.ndarray) -> np.ndarray:
    """Unit vectors (M, 3) spanning the null space of ``C - lam I`` (best of three row crosses).

    Where the null space is more than one-dimensional the result is arbitrary but unit length.
    """
    xx, xy, xz, yy, yz, zz = c
    ax, by, cz = xx - lam, yy - lam, zz - lam
    # rows r0 = (ax, xy, xz), r1 = (xy, by, yz), r2 = (xz, yz, cz)
    c01 = np.stack([xy * yz - xz * by, xz * xy - ax * yz, ax * by - xy * xy])
    c02 = np.stack([xy * cz - xz * yz, xz * xz - ax * cz, ax * yz - xy * xz])
    c12 = np.stack([by * cz - yz * yz, yz * xz - xy * cz, xy * yz - by * xz])
    n01, n02, n12 = (c01 * c01).sum(0), (c02 * c02).sum(0), (c12 * c12).sum(0)
    best = np.where(n01 >= n02, np.where(n01 >= n12, 0, 2), np.where(n02 >= n12, 1, 2))
    v = np.where(best == 0, c01, np.where(best == 1, c02, c12))
    n = np.sqrt(np.maximum(np.maximum(n01, n02), n12))
    ok = n > 0
    v = v / np.where(ok, n, 1.0)
    v[0, ~ok] = 1.0
    return np.ascontiguousarray(v.T)


def fit_planes(count: np.ndarray, s1: np.ndarray, s2: np.ndarray, nsum: np.ndarray
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares planes (paper eq. 1) from point moments; normals oriented by ``nsum``.

    ``count`` (M,), ``s1`` (3, M) sums of points, ``s2`` (6, M) sums of products xx, xy, xz,
    yy, yz, zz, ``nsum`` (3, M) sums of input normals.  Returns unit normals (M, 3), centroids
    (M, 3) and a mask of degenerate fits (a single point or collinear points), whose normal is
    the average input normal made orthogonal to the points' line.
    """
    m = s1 / count
    cov = s2 / count
    for r, (i, j) in enumerate(((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))):
        cov[r] -= m[i] * m[j]
    normal = np.empty((3, len(count)))           # filled as rows, returned transposed
    degenerate = count < 3
    full = np.flatnonzero(~degenerate)
    if len(full):
        c = cov[:, full]
        vals = symmetric_eigen(c)
        v = eigenvector(c, vals[2])
        # The closed-form eigenvalues carry sqrt(eps) relative error near a double root; one
        # Rayleigh-quotient step makes the smallest one accurate before taking its vector again.
        normal[:, full] = eigenvector(c, _rayleigh(c, v)).T
        # Spread along the second axis below ~0.03% of the first: a line (or a point), no plane.
        degenerate[full] = (vals[1] <= 1e-7 * vals[0]) | (vals[0] <= 0)
    # One point has no spread: its normal is its own (what _line_normals gives, without the work).
    single = np.flatnonzero(count == 1)
    a = nsum[:, single]
    a = a / np.maximum(np.sqrt((a * a).sum(0)), 1e-300)
    an = np.sqrt((a * a).sum(0))
    ok = an > 1e-12
    normal[:, single[ok]] = a[:, ok] / an[ok]
    rest = degenerate.copy()
    rest[single[ok]] = False
    if rest.any():
        normal[:, rest] = _line_normals(cov[:, rest], nsum[:, rest]).T
    flip = (normal * nsum).sum(0) < 0
    normal[:, flip] *= -1.0
    normal = normal.T
    return normal, np.ascontiguousarray(m.T), degenerate


def _line_normals(cov: np.ndarray, nsum: np.ndarray) -> np.ndarray:
    """Normals for points on a line (or one point): the average normal minus its part along the line.

    For collinear points the covariance is ``s^2 u u^T``, so its column with the largest diagonal
    entry points along the line ``u`` (coordinates are in the unit cube: 1e-20 is far below any
    octant's size squared, so smaller spreads count as a single point).  Works on contiguous
    component rows; this runs for most octants at the max depth.
    """
    xx, xy, xz, yy, yz, zz = cov
    use_y = yy > xx
    use_z = zz > np.maximum(xx, yy)
    u = np.stack([np.where(use_z, xz, np.where(use_y, xy, xx)),
                  np.where(use_z, yz, np.where(use_y, yy, xy)),
                  np.where(use_z, zz, np.where(use_y, yz, xz))])
    un = np.sqrt((u * u).sum(0))
    line = (np.maximum(np.maximum(xx, yy), zz) > 1e-20) & (un > 0)
    u /= np.where(un > 0, un, 1.0)
    a = nsum / np.maximum(np.sqrt((nsum * nsum).sum(0)), 1e-300)
    a -= np.where(line, (a * u).sum(0), 0.0) * u
    an = np.sqrt((a * a).sum(0))
    ok = an > 1e-12
    a /= np.where(ok, an, 1.0)
    if not ok.all():
        # The average normal vanishes (or lies along the line): any direction across the line.
        bad = np.flatnonzero(~ok)
        ub = np.where(line[bad], u[:, bad], [[0.0], [0.0], [1.0]]).T
        helper = np.where(np.abs(ub[:, :1]) < 0.9, [[1.0, 0.0, 0.0]], [[0.0, 1.0, 0.0]])
        perp = np.cross(ub, helper)
        a[:, bad] = (perp / np.linalg.norm(perp, axis=1, keepdims=True)).T
    return np.ascontiguousarray(a.T)


def _rayleigh(c: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v^T C v for unit vectors v (M, 3) and matrices given by components (6, M)."""
    x, y, z = v.T
    xx, xy, xz, yy, yz, zz = c
    return xx * x * x + yy * y * y + zz * z * z + 2.0 * (xy * x * y + xz * x * z + yz * y * z)


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
    as returned by :func:`cube_polygons` (all in the same local frame).
    """
    s = (points * normal).sum(1) + offset
    q = points - s[:, None] * normal
    return np.sqrt(s * s + _outside_distance_sq(q, normal, verts))


def _outside_distance_sq(q: np.ndarray, normal: np.ndarray, verts: np.ndarray) -> np.ndarray:
    """Squared distance from in-plane points ``q`` to their convex polygons (0 inside)."""
    a = verts
    b = np.roll(verts, -1, axis=1)
    e = b - a                                                           # (K, 6, 3)
    r = q[:, None] - a
    side = np.einsum("kij,kj->ki", np.cross(e, r), normal)
    inside = (side >= -1e-12 * np.einsum("kij,kij->ki", e, e).max(1, initial=0)[:, None]).all(1)
    ee = np.einsum("kij,kij->ki", e, e)
    t = np.clip(np.einsum("kij,kij->ki", r, e) / np.where(ee > 0, ee, 1.0), 0.0, 1.0)
    d = r - t[..., None] * e
    dist2 = np.einsum("kij,kij->ki", d, d).min(1)
    return np.where(inside, 0.0, dist2)


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
    # Per coordinate the grid is an outer sum of a row term and a column term.
    inside = None
    for c in range(3):
        r = foot[:, c, None] + g[None, :] * u[:, c, None]                # (M, k)
        q = g[None, :] * v[:, c, None]
        ok = np.abs(r[:, :, None] + q[:, None, :]) <= half
        inside = ok if inside is None else np.logical_and(inside, ok, out=inside)
    em, ek = np.nonzero(np.arange(MAX_POLYGON)[None] < count[:, None])
    # edge k runs from vertex k to vertex k + 1, the last one back to vertex 0
    nxt = np.where(ek + 1 < count[em], ek + 1, 0)
    return PatchProbes(u=u, v=v, foot=foot, g=g, grid=np.flatnonzero(inside),
                       edge_a=verts[em, ek], edge_b=verts[em, nxt],
                       edge_poly=em, per_edge=int(np.ceil(np.sqrt(2.0) * size / spacing)))


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
