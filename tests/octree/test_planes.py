"""The compiled plane fits of model.octree.planes and the build's plane offsets give what the
NumPy formulation they replaced gives (tests/octree/reference_planes.py), bit for bit, zero signs
included: element-wise arithmetic, NumPy's own arc cosine and cosines, sums in NumPy's order."""

from __future__ import annotations

import numpy as np
import pytest

from model.octree import keys
from model.octree.build import _place_planes
from model.octree.octree import PLANE_SCALE
from model.octree.planes import fit_planes, smallest_eigenvectors

from . import reference_planes as ref


def symmetric(kind: str, m: int, rng: np.random.Generator) -> np.ndarray:
    """(6, m) components of symmetric 3x3 matrices: general, planar (a double root), lines and
    zeros over many scales, small integers (exact ties)."""
    if kind == "general":
        a = rng.normal(size=(m, 3, 3))
        c = a @ a.transpose(0, 2, 1)
    elif kind == "planar":
        u = rng.normal(size=(m, 3))
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        c = np.eye(3)[None] * rng.random((m, 1, 1)) - 0.999999 * u[:, :, None] * u[:, None, :] * rng.random((m, 1, 1))
    elif kind == "lines":
        u = rng.normal(size=(m, 3))
        c = u[:, :, None] * u[:, None, :] * 10.0 ** rng.integers(-12, 3, (m, 1, 1))
        c[::7] = 0.0
    else:
        a = rng.integers(-3, 4, size=(m, 3, 3)).astype(float)
        c = a @ a.transpose(0, 2, 1)
    return np.stack([c[:, 0, 0], c[:, 0, 1], c[:, 0, 2], c[:, 1, 1], c[:, 1, 2], c[:, 2, 2]])


@pytest.mark.parametrize("kind", ["general", "planar", "lines", "integers"])
def test_smallest_eigenvectors_are_the_numpy_formulation_s_bit_for_bit(kind):
    c = symmetric(kind, 20_000, np.random.default_rng(len(kind)))
    values = ref.symmetric_eigen(c)
    first = ref.eigenvector(c, values[2])
    refined = ref.eigenvector(c, ref._rayleigh(c, first))
    got, got_values = smallest_eigenvectors(c)
    assert np.array_equal(got_values, values, equal_nan=True)
    assert np.array_equal(got, first, equal_nan=True)
    assert np.array_equal(np.signbit(got), np.signbit(first))
    assert np.array_equal(smallest_eigenvectors(c, refine=True)[0], refined, equal_nan=True)
    if kind == "general":          # and they are eigenvectors of the smallest eigenvalues
        mats = np.stack([c[[0, 1, 2]], c[[1, 3, 4]], c[[2, 4, 5]]]).transpose(2, 0, 1)
        lam = np.linalg.eigvalsh(mats)[:, 0]
        residual = np.einsum("mij,mj->mi", mats, got) - lam[:, None] * got
        assert np.abs(residual).max() < 1e-6 * np.abs(lam).max()


def moments(m: int, rng: np.random.Generator) -> tuple[np.ndarray, ...]:
    """Point moments of m octants of 1-5 points: scattered, collinear (two points are always a
    line), and normal sums that vanish or lie along the line (the rare branch)."""
    count = rng.integers(1, 6, m)
    pts = [rng.normal(size=(n, 3)) * 0.01 for n in count]
    for i in range(0, m, 5):                   # collinear
        pts[i] = rng.normal(size=(1, 3)) * 0.01 + rng.normal(size=(count[i], 1)) * rng.normal(size=(1, 3)) * 0.01
    nrm = [rng.normal(size=(n, 3)) for n in count]
    for i in range(0, m, 11):                  # normals cancelling out
        nrm[i] = np.zeros((count[i], 3))
    for i in range(3, m, 13):                  # the normal sum along the points' line
        d = pts[i][-1] - pts[i][0]
        nrm[i] = np.repeat(d[None] / max(np.linalg.norm(d), 1e-300), count[i], 0)
    s1 = np.stack([p.sum(0) for p in pts], 1)
    s2 = np.stack([np.array([(p[:, a] * p[:, b]).sum() for a, b in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))])
                   for p in pts], 1)
    nsum = np.stack([n.sum(0) for n in nrm], 1)
    return count, s1, s2, nsum


def test_fit_planes_are_the_numpy_formulation_s_bit_for_bit():
    count, s1, s2, nsum = moments(6000, np.random.default_rng(3))
    got, want = fit_planes(count, s1, s2, nsum), ref.fit_planes(count, s1, s2, nsum)
    for a, b in zip(got, want):
        assert np.array_equal(a, b, equal_nan=True)
        assert np.array_equal(np.signbit(a), np.signbit(b))           # zeros keep their sign too
    normal, _, degenerate = got
    assert np.allclose(np.linalg.norm(normal, axis=1), 1.0)
    assert degenerate[count < 3].all() and degenerate[::5].all()      # two points and collinear ones


def test_fit_planes_keep_the_sign_of_zeros_and_refuse_empty_octants():
    """Axis-aligned points and normals give signed zeros; NumPy's sums start at +0.0 (and its
    reductions at -0.0): the kernels' must give the same signs.  An octant without points has no
    plane."""
    count, s1, s2, nsum = moments(400, np.random.default_rng(7))
    s1[1], s2[[1, 3, 4]], nsum[2] = -0.0, -0.0, -0.0            # every point on y = 0, normals in that plane
    nsum[1, ::3] = -0.0
    got, want = fit_planes(count, s1, s2, nsum), ref.fit_planes(count, s1, s2, nsum)
    assert (got[0] == 0).any()
    for a, b in zip(got, want):
        assert np.array_equal(a, b, equal_nan=True) and np.array_equal(np.signbit(a), np.signbit(b))
    # two points on the x axis: the normal sum's part along the line is a sum of -0.0 terms
    h = float.fromhex
    two = (np.array([2]), np.array([[h("0x1.7852f4c9381c3p-7")], [-0.0], [-0.0]]),
           np.array([[h("0x1.c88bffd712f06p-14")], [h("0x1.93cc3912dcb0ap-16")], [-0.0], [-0.0], [-0.0],
                     [h("0x1.2791b4acf350cp-13")]]),
           np.array([[h("-0x1.3cefe8dd4eab3p-1")], [h("0x1.08a5d2b06e6cfp-1")], [-0.0]]))
    got, want = fit_planes(*two)[0], ref.fit_planes(*two)[0]
    assert np.array_equal(got, want) and np.array_equal(np.signbit(got), np.signbit(want))
    with pytest.raises(ValueError, match="at least one point"):
        fit_planes(np.array([2, 0]), s1[:, :2], s2[:, :2], nsum[:, :2])


def test_plane_offsets_are_the_numpy_formulation_s_with_the_sign_of_zeros():
    """The build's planes (centre from the key, offset ``n . (centre - (centroid + 0.5))``, stored
    as float32 over ``PLANE_SCALE * size``): the NumPy formulation's numbers and zero signs."""
    rng = np.random.default_rng(8)
    depth, m = 6, 3000
    key = keys.encode(rng.integers(0, 1 << depth, (m, 3)), rng.integers(0, 3, m))    # batch bits set too
    size = 1.0 / (1 << depth)
    normal = rng.normal(size=(m, 3))
    normal[::4] = np.where(rng.random((len(normal[::4]), 3)) < 0.5, -0.0, 1.0) * np.sign(normal[::4])
    centre = (keys.decode(key)[0] + 0.5) * size
    centroid = centre - 0.5 + rng.normal(size=(m, 3)) * size * 0.1
    centroid[::3] = centre[::3] - 0.5                        # planes through the centre: offsets of zero
    nonempty = np.ones(m, bool)
    got_centre, got_offset, plane = np.empty((m, 3)), np.empty(m), np.zeros((m, 4), np.float32)
    _place_planes(key, nonempty, normal, centroid, size, PLANE_SCALE * size, got_centre, got_offset, plane)
    offset = (normal * (centre - (centroid + 0.5))).sum(1)
    assert np.array_equal(got_centre, centre) and np.array_equal(got_offset, offset)
    want = np.zeros((m, 4), np.float32)
    want[:, :3], want[:, 3] = normal, offset / (PLANE_SCALE * size)
    assert np.array_equal(plane, want) and np.array_equal(np.signbit(plane), np.signbit(want))
    assert (offset[::3] == 0).all()
