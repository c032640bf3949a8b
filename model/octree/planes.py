"""Least-squares planes of point sets (paper eq. 1) from their moments: the smallest eigenvector
of each 3x3 covariance in closed form (the trigonometric method), refined by a Rayleigh step, and
the degenerate cases (one point, points on a line) oriented by the points' normals.

Compiled (numba), node by node, in the order of the NumPy formulation they replaced, which
``tests/octree/reference_planes.py`` keeps: the same bits, zero signs included; the arc cosine and
cosines are NumPy's own, called between the kernels.
"""

from __future__ import annotations

import numpy as np

from .jit import compiled, inlined


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
    normal, degenerate = np.empty((m, 3)), np.empty(m, np.bool_)
    _plane_normals(count, cov, nsum, q, p, np.cos(phi), np.cos(phi + 2.0 * np.pi / 3.0), normal, degenerate)
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
def _plane_normals(count, cov, nsum, q, p, cos1, cos3, normal, degenerate) -> None:
    """Each node's oriented normal (M, 3) and whether its fit is degenerate."""
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
            n0, n1, n2 = _line_normal(cov[0, i], cov[1, i], cov[2, i], cov[3, i], cov[4, i], cov[5, i],
                                      nsum[0, i], nsum[1, i], nsum[2, i])
        if n0 * nsum[0, i] + n1 * nsum[1, i] + n2 * nsum[2, i] < 0:
            n0, n1, n2 = -n0, -n1, -n2
        normal[i, 0], normal[i, 1], normal[i, 2] = n0, n1, n2


@inlined
def _line_normal(xx, xy, xz, yy, yz, zz, s0, s1, s2) -> tuple[float, float, float]:
    """A normal for points on a line (or one point): the average normal ``s`` minus its part along
    the line.  For collinear points the covariance is ``s^2 u u^T``, so its column with the largest
    diagonal entry points along the line ``u`` (coordinates are in the unit cube: 1e-20 is far
    below any octant's size squared, so smaller spreads count as a single point).  Where that
    leaves no direction (the average normal vanishes or lies along the line): a direction across
    the line (across z where there is no line), the line crossed with x, or with y when the line
    runs near x."""
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
    if an > 1e-12:
        return a0 / an, a1 / an, a2 / an
    if not line:
        u0, u1, u2 = 0.0, 0.0, 1.0
    h0, h1 = (1.0, 0.0) if abs(u0) < 0.9 else (0.0, 1.0)
    c0, c1, c2 = u1 * 0.0 - u2 * h1, u2 * h0 - u0 * 0.0, u0 * h1 - u1 * h0      # u x (h0, h1, 0)
    cn = np.sqrt(c0 * c0 + c1 * c1 + c2 * c2)
    return c0 / cn, c1 / cn, c2 / cn
