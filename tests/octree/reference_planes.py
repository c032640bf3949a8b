"""The NumPy formulation that :mod:`model.octree.planes` (the plane fits: trigonometric
eigenvalues, the null vector as the best of three row crosses, one Rayleigh step, the line
normals) and :mod:`model.octree.geometry` (the polygon distances) compiled, kept as the reference
the kernels must equal."""

from __future__ import annotations

import numpy as np


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


def _rayleigh(c: np.ndarray, v: np.ndarray) -> np.ndarray:
    """v^T C v for unit vectors v (M, 3) and matrices given by components (6, M)."""
    x, y, z = v.T
    xx, xy, xz, yy, yz, zz = c
    return xx * x * x + yy * y * y + zz * z * z + 2.0 * (xy * x * y + xz * x * z + yz * y * z)


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
