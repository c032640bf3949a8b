"""The closed surface of decoded and ground-truth octrees: closed, consistently oriented outward,
2-manifold, of positive volume and of the right topology; sharp corners kept; thin parts closed;
touching parts not fused into a non-manifold edge; robust to octrees no shape would give."""

from __future__ import annotations

import manifold3d
import numpy as np
import pytest
import trimesh
from scipy.spatial import cKDTree

from model.octree import LEAF, build_octree
from model.surface import MIN_COMPONENT_FACES, SURFACES, is_closed, surface_mesh, watertight_mesh
from model.surface.checks import WELD, is_closed_embedded
from model.surface.crossing import crossing_faces
from model.surface.dmc import APART, apart
from model.surface.tables import COMPONENTS, CORNER_COMPONENT, REPAIR, boundary_loops, components

from ..meshes import mesh_path
from ..octree.conftest import mesh_points, sphere_points


def check_closed(m, simplified: bool = False) -> trimesh.Trimesh:
    """Assert everything a closed mesh promises, with two independent checkers; return it.
    ``simplified``: made to a face budget, where a small part may keep fewer faces than the
    contour's smallest component."""
    mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert m.closed and is_closed(m.faces)
    assert mesh.is_watertight and mesh.is_winding_consistent and mesh.volume > 0
    edges = np.sort(mesh.edges, axis=1)
    assert np.all(np.unique(edges, axis=0, return_counts=True)[1] == 2)      # no edge of 4 faces
    _vertex_fans_are_single(mesh)
    solid = manifold3d.Manifold(manifold3d.Mesh(vert_properties=m.vertices.astype(np.float32),
                                                tri_verts=m.faces.astype(np.uint32)))
    assert solid.status() == manifold3d.Error.NoError
    if not simplified:
        assert min(len(c.faces) for c in mesh.split(only_watertight=False)) >= MIN_COMPONENT_FACES
    _closed_as_a_welding_reader_loads_it(m)
    return mesh


def _closed_as_a_welding_reader_loads_it(m) -> None:
    """No two vertices closer than WELD of the box, and trimesh's default load (which merges
    vertices by position) finds every vertex and a closed, consistently wound mesh."""
    diag = np.linalg.norm(m.vertices.max(0) - m.vertices.min(0))
    assert not len(cKDTree(m.vertices).query_pairs(WELD * diag)), "vertices a welding reader merges"
    welded = trimesh.Trimesh(m.vertices, m.faces)
    assert len(welded.vertices) == len(m.vertices) and welded.is_watertight and welded.is_winding_consistent
    assert is_closed_embedded(m.vertices, m.faces)


def _vertex_fans_are_single(mesh: trimesh.Trimesh) -> None:
    """Every vertex's faces form one fan (its link is one cycle): no pinched vertex."""
    f = mesh.faces
    for v in np.unique(f)[:: max(1, len(np.unique(f)) // 400)]:          # a sample of the vertices
        rows = f[(f == v).any(1)]
        links = [tuple(r[(np.flatnonzero(r == v)[0] + k) % 3] for k in (1, 2)) for r in rows]
        nxt = dict(links)
        start = links[0][0]
        seen, cur = 0, start
        while True:
            cur = nxt[cur]
            seen += 1
            if cur == start:
                break
        assert seen == len(links), f"vertex {v}: its faces form more than one fan"


def octree_of(mesh: trimesh.Trimesh, depth: int, n: int = 150_000):
    return build_octree(mesh_points(mesh, n), depth, neighbors=False)


def test_the_tables_give_disks_that_meet_each_face_once():
    for config in range(256):
        if REPAIR[config] >= 0:
            continue
        groups = components(config) if 0 < config < 255 else []
        assert COMPONENTS[config] == len(groups)
        for k, group in enumerate(groups):
            assert boundary_loops(config, group) == 1
            assert set(np.flatnonzero(CORNER_COMPONENT[config] == k)) == set(group)
    assert 0 < (REPAIR >= 0).sum() < 64


@pytest.mark.parametrize("shape, genus", [("sphere", 0), ("torus", 1), ("knot.ply", 1), ("cad_block.stl", 2)])
@pytest.mark.parametrize("depth", [5, 6, 7])
def test_closed_with_the_genus_of_the_shape(shape, genus, depth):
    if shape == "sphere":
        o = build_octree(sphere_points(60_000), depth, neighbors=False)
    elif shape == "torus":
        o = octree_of(trimesh.creation.torus(1.0, 0.35, major_sections=96, minor_sections=48), depth)
    else:
        o = octree_of(trimesh.load(mesh_path(shape), force="mesh"), depth)
    m = watertight_mesh(o)
    mesh = check_closed(m)
    assert mesh.body_count == 1 and mesh.euler_number == 2 - 2 * genus
    if shape == "sphere":        # smooth and thick: no face crosses another (the torus, the cube, a plate still have some)
        assert not crossing_faces(m.vertices, m.faces).any()


@pytest.mark.parametrize("depth", [5, 6])
def test_a_cube_keeps_its_corners_and_flat_faces(depth):
    box = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    o = octree_of(box, depth)
    m = watertight_mesh(o)
    mesh = check_closed(m)
    h = 1.0 / 0.96 / (1 << depth)                                # a cell in the input's units
    corners = np.array([[x, y, z] for x in (-0.5, 0.5) for y in (-0.5, 0.5) for z in (-0.5, 0.5)])
    nearest = np.linalg.norm(mesh.vertices[None] - corners[:, None], axis=2).min(1)
    assert nearest.max() <= h and nearest.mean() <= 0.4 * h, nearest / h      # sharp: within a fraction of a cell
    assert mesh.volume == pytest.approx(1.0, rel=6 * h)
    corner_gap = np.abs(np.abs(mesh.vertices[mesh.faces]) - 0.5)             # (F, 3 corners, 3 axes)
    on_side = (corner_gap <= 0.1 * h).all(1).any(1)              # all three corners on one side of the cube
    area = mesh.area_faces / h ** 2
    assert area[on_side].sum() / area.sum() > 0.75               # flat sides stay flat
    assert np.median(area[on_side]) >= 2.0 * (depth - 4)         # ... made of faces larger than a cell's half
    assert len(m.faces) < 0.3 * len(watertight_mesh(o, merge=False).faces)


@pytest.mark.parametrize("thickness_cells", [0.3, 1.0])
def test_a_plate_thinner_than_a_cell_stays_present_and_closed(thickness_cells):
    depth = 6
    h = 1.0 / 0.96 / (1 << depth)
    plate = trimesh.creation.box(extents=(1.0, thickness_cells * h, 0.7))
    o = octree_of(plate, depth)
    mesh = check_closed(watertight_mesh(o))
    assert mesh.body_count == 1 and mesh.euler_number == 2
    patches = surface_mesh(o, "patches").vertices
    ext, patch_ext = mesh.extents, patches.max(0) - patches.min(0)     # the patches overhang the ends too
    assert ext[0] == pytest.approx(1.0, abs=2.5 * h) and ext[2] == pytest.approx(0.7, abs=2.5 * h)
    assert np.all(ext[[0, 2]] <= patch_ext[[0, 2]] + h)
    assert ext[1] <= 3 * h                                       # thickened to about a cell, no more
    assert mesh.area == pytest.approx(2 * 0.7, rel=0.15)


def test_two_cubes_touching_along_an_edge_do_not_fuse_into_a_non_manifold_edge():
    a = trimesh.creation.box(extents=(0.5, 0.5, 0.5), transform=trimesh.transformations.translation_matrix((-0.25, -0.25, 0)))
    b = trimesh.creation.box(extents=(0.5, 0.5, 0.5), transform=trimesh.transformations.translation_matrix((0.25, 0.25, 0)))
    check_closed(watertight_mesh(octree_of(trimesh.util.concatenate([a, b]), 6)))


@pytest.mark.parametrize("name", ["chair_soup.off", "airplane_soup.stl", "blob.obj"])
def test_real_meshes_and_polygon_soups(name):
    """Soups sampled as they are keep their overlapping parts' inner faces (the dataset's scans
    drop them): the airplane's tailplane, thinner than a cell and crossing the fin's inner faces,
    comes out as two closed pieces (3% of the faces) where its scan is one solid."""
    mesh = check_closed(watertight_mesh(octree_of(trimesh.load(mesh_path(name), force="mesh"), 6)))
    assert max(len(b.faces) for b in mesh.split(only_watertight=False)) >= 0.95 * len(mesh.faces)


@pytest.mark.parametrize("seed", range(6))
def test_any_octree_gives_a_closed_mesh(seed):
    """Random leaves with random planes (what an untrained decoder gives): still closed."""
    rng = np.random.default_rng(seed)
    o = build_octree(sphere_points(20_000, seed=seed), 5, neighbors=False)
    for lv in o.levels:
        leaf = lv.label == LEAF
        lv.plane[leaf, :3] = rng.normal(size=(int(leaf.sum()), 3))
        lv.plane[leaf, 3] = rng.uniform(-1, 1, int(leaf.sum()))
        flip = rng.random(len(lv)) < 0.1                         # and some octants predicted empty
        lv.label[leaf & flip] = 0
    m = watertight_mesh(o)
    if len(m.faces):
        check_closed(m)


def test_an_octree_without_leaves_gives_an_empty_mesh_and_surfaces_are_named():
    o = build_octree(sphere_points(5000), 4, neighbors=False)
    for lv in o.levels:
        lv.label[lv.label == LEAF] = 0
    m = watertight_mesh(o)
    assert len(m.faces) == 0 and m.closed
    assert SURFACES == ("watertight", "patches")
    with pytest.raises(ValueError, match="watertight, patches"):
        surface_mesh(o, "smooth")


@pytest.mark.parametrize("budget, volume_change", [(4000, 0.05), (800, 0.2)])
def test_a_face_budget_is_met_and_the_mesh_stays_closed(budget, volume_change):
    o = octree_of(trimesh.load(mesh_path("knot.ply"), force="mesh"), 6)
    full = watertight_mesh(o)
    m = surface_mesh(o, "watertight", faces=budget)
    assert len(full.faces) > 2.5 * budget and len(m.faces) <= budget
    mesh = check_closed(m, simplified=True)
    assert mesh.euler_number == 0                                   # still a knot
    assert len(m.vertex_depth) == len(m.vertices)
    full_mesh = trimesh.Trimesh(full.vertices, full.faces, process=False)
    assert mesh.volume == pytest.approx(full_mesh.volume, rel=volume_change)     # a tube at 800 faces thins
    with pytest.raises(ValueError, match="watertight surface only"):
        surface_mesh(o, "patches", faces=budget)


@pytest.mark.parametrize("name, budget", [("chair_soup.off", 3000), ("airplane_soup.stl", 1000)])
def test_a_face_budget_never_makes_two_surfaces_touch(name, budget):
    """Simplifying these far enough collapses a thin part's two sides onto each other (closed in the
    index buffer, pinched once welded); the mesh returned is the last one closed as embedded,
    with more faces than asked, and fewer than the unsimplified surface's."""
    o = octree_of(trimesh.load(mesh_path(name), force="mesh"), 6)
    m = surface_mesh(o, "watertight", faces=budget)
    check_closed(m, simplified=True)
    assert len(m.faces) < len(watertight_mesh(o).faces)


def test_a_thin_plate_whose_planes_point_either_way_has_no_holes():
    """One plane stands for both faces of a part thinner than a cell, so its orientation is a
    guess; with every other leaf's plane flipped the plate still comes out whole (genus 0)."""
    depth = 6
    h = 1.0 / 0.96 / (1 << depth)
    o = octree_of(trimesh.creation.box(extents=(1.0, 0.4 * h, 0.7)), depth)
    flipped = 0
    for lv in o.levels:
        leaf = np.flatnonzero(lv.label == LEAF)[::2]
        lv.plane[leaf] *= -1                                     # normal and offset: the same plane, other side
        flipped += len(leaf)
    assert flipped > 50
    mesh = check_closed(watertight_mesh(o))
    assert mesh.body_count == 1 and mesh.euler_number == 2
    assert mesh.area == pytest.approx(2 * 0.7, rel=0.15)


def test_vertices_at_one_position_that_would_move_alike_are_parted():
    """Two vertices at one point, in one cell, whose faces have the same centre (the same triangle
    wound both ways): moved alike they would stay together; the lower one alone moves on."""
    h = 1.0 / 64
    p = np.array([0.5, 0.5, 0.5])
    verts = np.array([p, p, p + [h, 0, 0], p + [0, h, 0], p + [0, 0, h], p + [h, h, 0]])
    faces = np.array([[0, 2, 3], [1, 3, 2], [0, 4, 5], [1, 5, 4]])
    centre = np.repeat(p[None] + h / 2, len(verts), axis=0)
    out = apart(verts, faces, centre, h)
    assert np.linalg.norm(out[0] - out[1]) >= 0.5 * APART * h
    assert np.array_equal(out[2:], verts[2:])
    assert not len(cKDTree(out).query_pairs(0.1 * APART * h))
