"""The compiled polygon distances and probe grids of model.octree.geometry give what the NumPy
formulation they replaced gives (tests/octree/reference_planes.py): the probe grids bit for bit,
the distances within rounding, because NumPy's einsum picks its order of addition by the CPU's
instruction set."""

from __future__ import annotations

import numpy as np
import pytest

from model.octree.geometry import cube_polygons, patch_probes, plane_basis, polygon_distance

from . import reference_planes as ref


def polygons(m: int, rng: np.random.Generator):
    normal = rng.normal(size=(m, 3))
    normal[::4] = np.round(normal[::4])                 # planes along the axes
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    size = 10.0 ** rng.uniform(-3, 0)
    offset = rng.uniform(-0.9, 0.9, m) * size
    verts, count = cube_polygons(normal, offset, size)
    keep = count > 0
    return normal[keep], offset[keep], verts[keep], count[keep], size


def test_polygon_distances_are_the_numpy_formulation_s_within_rounding():
    rng = np.random.default_rng(4)
    normal, offset, verts, _, size = polygons(20_000, rng)
    pts = rng.uniform(-0.6, 0.6, (len(normal), 3)) * size
    pts[:500] = verts[:500, 0]                          # on a vertex: distance to the plane only
    got = polygon_distance(pts, normal, offset, verts)
    assert np.abs(got - ref.polygon_distance(pts, normal, offset, verts)).max() <= 1e-15 * size
    assert got[:500].max() <= 1e-15 * size


def test_polygon_distance_of_a_square():
    square = np.array([[[-1.0, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0], [-1, 1, 0], [-1, 1, 0]]])
    n, off = np.array([[0.0, 0, 1]]), np.array([0.0])
    for p, d in (((0.5, 0.2, 3.0), 3.0), ((4.0, 0.0, 0.0), 3.0), ((4.0, 5.0, 0.0), 5.0), ((4.0, 5.0, 12.0), 13.0)):
        assert polygon_distance(np.array([p]), n, off, square)[0] == pytest.approx(d, rel=1e-15)


def grid_reference(normal, offset, size, spacing):
    """The probes inside each cube as the NumPy formulation found them."""
    u, v = plane_basis(normal)
    radius = np.sqrt(3.0) / 2.0 * size
    k = int(np.ceil(2.0 * radius / spacing)) + 1
    g = np.linspace(-radius, radius, k)
    foot = -offset[:, None] * normal
    half = size / 2.0 * (1.0 + 1e-9)
    inside = None
    for c in range(3):
        r = foot[:, c, None] + g[None, :] * u[:, c, None]
        q = g[None, :] * v[:, c, None]
        ok = np.abs(r[:, :, None] + q[:, None, :]) <= half
        inside = ok if inside is None else inside & ok
    return np.flatnonzero(inside)


@pytest.mark.parametrize("cells", [1, 4, 32])
def test_probe_grids_are_the_numpy_formulation_s(cells):
    normal, offset, verts, count, size = polygons(3000, np.random.default_rng(cells))
    spacing = size / cells
    probes = patch_probes(normal, offset, verts, count, size, spacing)
    want = grid_reference(normal, offset, size, spacing)
    assert len(want) >= len(normal) // 2
    assert np.array_equal(probes.grid, want)
