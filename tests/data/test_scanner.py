"""Virtual scanner: points on the surface, outward normals, both engines agree."""

import numpy as np
import pytest
import trimesh
from trimesh.triangles import points_to_barycentric

from model.data.layouts import load_mesh
from model.data.scanner import embree_available, scan, scan_detailed, scanner_directions
from model.data.shapes import generate

from ..meshes import mesh_names, mesh_path

SOUPS = ["chair_soup.off", "airplane_soup.stl"] + [n for n in mesh_names() if n == "mn40_chair_0001.off"]


def _assert_on_hit_faces(mesh, s, tol):
    tri = np.asarray(mesh.triangles)[s.face]
    p = s.points.astype(np.float64)
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    plane = np.abs(np.einsum("ij,ij->i", p - tri[:, 0], n))
    assert plane.max() < tol
    bary = points_to_barycentric(tri, p)
    assert bary.min() > -1e-3


def test_directions():
    d = scanner_directions()
    assert d.shape == (14, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0)
    assert len(np.unique(np.round(d, 6), axis=0)) == 14


@pytest.mark.parametrize("engine", ["raster"] + (["embree"] if embree_available() else []))
@pytest.mark.parametrize("shape", ["sphere", "box"])
def test_outward_normals_on_closed_shapes(engine, shape):
    mesh = trimesh.creation.icosphere(3) if shape == "sphere" else trimesh.creation.box([1.0, 0.6, 0.3])
    # Flip half of the faces: the scanner must still orient normals outward.
    faces = mesh.faces.copy()
    faces[::2] = faces[::2, ::-1]
    mesh = trimesh.Trimesh(mesh.vertices, faces, process=False)
    pts, nrm = scan(mesh, resolution=64, engine=engine)
    assert pts.dtype == np.float32 and nrm.dtype == np.float32
    assert len(pts) > 5000
    assert (np.einsum("ij,ij->i", nrm, pts) > 0).all()
    np.testing.assert_allclose(np.linalg.norm(nrm, axis=1), 1.0, atol=1e-5)
    if shape == "sphere":
        r = np.linalg.norm(pts, axis=1)
        assert r.max() <= 1.0 + 1e-5 and r.min() > 0.98  # icosphere(3) facets sag < 2 %


def test_points_on_surface_and_engines_agree():
    mesh = generate("chair", 2)
    a = scan_detailed(mesh, resolution=96, engine="raster")
    _assert_on_hit_faces(mesh, a, 1e-5)
    if embree_available():
        b = scan_detailed(mesh, resolution=96, engine="embree")
        assert abs(len(a.points) - len(b.points)) <= 0.01 * len(a.points)
        _assert_on_hit_faces(mesh, b, 1e-5)


def test_hidden_inner_part_is_dropped():
    outer = trimesh.creation.box([1.0, 1.0, 1.0])
    inner = trimesh.creation.box([0.5, 0.5, 0.5])
    soup = trimesh.Trimesh(np.r_[outer.vertices, inner.vertices], np.r_[outer.faces, inner.faces + 8], process=False)
    s = scan_detailed(soup, resolution=48, engine="raster")
    assert len(s.points) > 0 and s.face.max() < len(outer.faces)
    assert np.abs(s.points).max(axis=1).min() > 0.5 - 1e-6


def test_jittered_grid_changes_points():
    mesh = trimesh.creation.box()
    a, _ = scan(mesh, resolution=32, engine="raster")
    b, _ = scan(mesh, resolution=32, rng=np.random.default_rng(1), engine="raster")
    assert not np.array_equal(a[: min(len(a), len(b))], b[: min(len(a), len(b))])
    assert np.abs(b).max() <= 0.5 + 1e-6


def test_empty_mesh_raises():
    with pytest.raises(ValueError, match="empty"):
        scan(trimesh.Trimesh())


def test_generated_polygon_soup():
    """What the real soup below guards, on a generated input that exists wherever the suite runs:
    40 overlapping boxes, unmerged, a third of their faces flipped, not watertight."""
    rng = np.random.default_rng(3)
    parts = []
    for _ in range(40):
        box = trimesh.creation.box(rng.uniform(0.05, 0.5, 3))
        box.apply_translation(rng.uniform(-0.4, 0.4, 3))
        faces = box.faces.copy()
        flip = rng.random(len(faces)) < 0.33
        faces[flip] = faces[flip][:, ::-1]
        keep = rng.random(len(faces)) > 0.1                     # holes: not watertight
        parts.append(trimesh.Trimesh(box.vertices, faces[keep], process=False))
    mesh = trimesh.util.concatenate(parts)
    assert not mesh.is_watertight
    s = scan_detailed(mesh, resolution=96)
    scale = float(np.linalg.norm(mesh.extents))
    _assert_on_hit_faces(mesh, s, 1e-5 * scale)
    assert len(s.points) > 10000
    assert set(np.unique(s.view)) == set(range(14))
    # flipped faces do not flip normals: each faces the scanner view that saw it
    assert (np.einsum("ij,ij->i", s.normals, scanner_directions()[s.view]) < 0).all()


@pytest.mark.parametrize("name", SOUPS)
def test_real_polygon_soup(name):
    mesh = load_mesh(mesh_path(name))  # overlapping parts, not watertight as a whole
    s = scan_detailed(mesh, resolution=96)
    scale = float(np.linalg.norm(mesh.extents))
    _assert_on_hit_faces(mesh, s, 1e-5 * scale)
    assert len(s.points) > 10000
    assert set(np.unique(s.view)) == set(range(14))
