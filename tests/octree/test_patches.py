import numpy as np
import pytest
import trimesh

from model.octree import build_octree
from model.octree.geometry import MAX_POLYGON, cube_polygons, plane_basis
from model.octree.metrics import chamfer_distance, hausdorff_distance, sample_patches
from model.octree.patches import leaf_patches, patch_mesh, patch_triangles, patches_to_mesh

from .conftest import sphere_points


def test_cube_polygons_lie_in_their_cube_on_their_plane_and_turn_about_n():
    rng = np.random.default_rng(0)
    n = rng.normal(size=(5000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[:300] = np.eye(3)[rng.integers(0, 3, 300)] * rng.choice([-1, 1], (300, 1))  # axis-aligned
    off = rng.uniform(-0.86, 0.86, 5000) * 2.0
    off[:300] = rng.uniform(-1, 1, 300)
    verts, cnt = cube_polygons(n, off, 2.0)
    hit = np.abs(off) < np.abs(n).sum(1)               # the plane meets the cube [-1, 1]^3
    assert np.all(cnt[hit] >= 3) and np.all(cnt <= 6) and np.all(cnt[~hit] == 0)
    v = verts[hit]
    assert np.abs(v).max() <= 1 + 1e-9
    assert np.abs(np.einsum("mkj,mj->mk", v, n[hit]) + off[hit][:, None]).max() < 1e-9
    for i in np.flatnonzero(hit)[:500]:
        p = verts[i, :cnt[i]]
        for k in range(1, cnt[i] - 1):
            tri_n = np.cross(p[k] - p[0], p[k + 1] - p[0])
            assert tri_n @ n[i] >= -1e-12
    # Six vertices for a plane through the centre perpendicular to a diagonal.
    d = np.full((1, 3), 1 / np.sqrt(3))
    assert cube_polygons(d, np.zeros(1), 2.0)[1][0] == 6


def test_plane_basis_is_numpys_cross_and_norm_bit_for_bit():
    """The compiled basis against the NumPy formulation it replaced, on random normals, axis-aligned
    ones, ties between components (the first smallest one chosen), float32-rounded and zero ones."""
    rng = np.random.default_rng(2)
    n = rng.normal(size=(20_000, 3))
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n[:300] = np.eye(3)[rng.integers(0, 3, 300)] * rng.choice([-1, 1], (300, 1))
    n[300:600] = np.round(n[300:600], 1)
    n[600:700, 0] = -n[600:700, 1]
    n[700:800] = n[700:800].astype(np.float32)
    n[800:810] = 0.0
    axis = np.zeros_like(n)
    axis[np.arange(len(n)), np.argmin(np.abs(n), axis=1)] = 1.0
    with np.errstate(invalid="ignore"):
        u = np.cross(n, axis)
        u /= np.linalg.norm(u, axis=1, keepdims=True)
    v = np.cross(n, u)
    ours_u, ours_v = plane_basis(n)
    np.testing.assert_array_equal(ours_u, u)
    np.testing.assert_array_equal(ours_v, v)
    assert np.isnan(ours_u[800:810]).all() and not np.isnan(ours_u[:800]).any()


def test_patch_mesh_is_in_input_coordinates_inside_cubes_and_faces_along_n():
    pts, nrm = sphere_points(60_000, radius=3.0)
    pts = pts + np.array([10.0, -4.0, 2.0])
    o = build_octree((pts, nrm), 6)
    patches = leaf_patches(o)
    assert len(patches) == sum(o.leaves_per_depth())
    rel = patches.vertices - patches.center[:, None]
    assert np.all(np.abs(rel) <= patches.size[:, None, None] / 2 * (1 + 1e-9))
    mesh = patches_to_mesh(o)
    assert np.allclose(mesh.bounds, [[7, -7, -1], [13, -1, 5]], atol=0.15)
    face_patch = np.repeat(np.arange(len(patches)), patches.count - 2)
    assert len(mesh.faces) == len(face_patch)
    dots = (mesh.face_normals * patches.normal[face_patch]).sum(1)
    assert np.all(dots > 0.999)
    # Outward: the sphere's patches face away from its centre.
    centroid = mesh.triangles_center - np.array([10.0, -4.0, 2.0])
    assert np.all((mesh.face_normals * centroid).sum(1) > 0)
    radius = np.linalg.norm(mesh.vertices - np.array([10.0, -4.0, 2.0]), axis=1)
    thr_world = o.threshold * o.normalizations[0].scale
    assert np.abs(radius - 3.0).max() <= 1.05 * thr_world


def test_colored_mesh_exports_to_ply_glb_obj(tmp_path):
    pts, nrm = sphere_points(20_000)
    mesh = patches_to_mesh(build_octree((pts, nrm), 5), color_by_depth=True)
    assert mesh.visual.face_colors.shape == (len(mesh.faces), 4)
    for ext in ("ply", "glb", "obj"):
        path = tmp_path / f"m.{ext}"
        mesh.export(path)
        back = trimesh.load(path, force="mesh", process=False)
        assert abs(back.area - mesh.area) < 1e-6 * mesh.area


def test_patch_samples_at_128_cubed_have_small_chamfer_to_the_surface():
    """Depth-7 patches of a unit sphere sampled at 128^3: the Chamfer distance is at the sampling
    floor (as many points drawn straight from the sphere: ~0.28 voxel^2), Hausdorff < 1.5 voxels."""
    pts, nrm = sphere_points(300_000)
    o = build_octree((pts, nrm), 7)
    samples = sample_patches(o, resolution=128, seed=1)
    truth, _ = sphere_points(200_000, seed=2)
    cd = chamfer_distance(truth, samples)
    voxel = o.normalizations[0].scale / 128
    floor = chamfer_distance(truth, sphere_points(len(samples), seed=3)[0])
    assert cd < 0.35 * voxel ** 2 and cd < 1.1 * floor
    assert hausdorff_distance(truth, samples) < 1.5 * voxel
    # One point per sub-patch: about as many points as surface voxels at 128^3.
    assert 0.5 < len(samples) / (4 * np.pi / voxel ** 2) < 2.0


def test_chamfer_matches_the_paper_formula_on_a_tiny_case():
    a = np.array([[0.0, 0, 0], [1.0, 0, 0]])
    b = np.array([[0.0, 0, 0.5]])
    # a->b: (0.25 + 1.25) / 2; b->a: 0.25
    assert np.isclose(chamfer_distance(a, b), 0.75 + 0.25)
    assert np.isclose(hausdorff_distance(a, b), np.sqrt(1.25))


@pytest.mark.parametrize("world", [True, False])
def test_patch_mesh_is_the_leaf_patches_fanned_bit_for_bit(world):
    """The compiled patch mesh equals the NumPy formulation it replaced: every leaf patch's
    polygon (:func:`leaf_patches`) fanned (:func:`patch_triangles`), the padding dropped, in
    world coordinates by the octree's normalisation."""
    pts, nrm = sphere_points(30_000, radius=2.0)
    o = build_octree((pts + np.array([3.0, 1.0, -2.0]), nrm), 6)
    patches = leaf_patches(o)
    verts, faces = patch_triangles(patches)
    used = np.flatnonzero((np.arange(MAX_POLYGON)[None] < patches.count[:, None]).ravel())
    remap = np.full(len(verts), -1, np.int64)
    remap[used] = np.arange(len(used))
    want = verts[used]
    if world:
        want = o.normalizations[0].to_world(want)
    got = patch_mesh(o, world)
    assert np.array_equal(got.vertices, want)
    assert np.array_equal(got.faces, remap[faces]) and got.faces.dtype == np.int64
    assert np.array_equal(got.vertex_depth, np.repeat(patches.depth, MAX_POLYGON)[used])
    assert len(got.faces) == int((patches.count - 2).sum()) > 1000
