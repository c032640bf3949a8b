"""Faces that cross other faces: hand-made pairs for each rule, the narrow test against an
independent formulation on random triangles, and the grid's candidate pairs against every pair."""

import itertools

import numpy as np
import pytest
import trimesh

from model.surface.crossing import _faces_cross, crossing_faces

TRI = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


def pair(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two separate triangles (no common vertex) cross, as the mesh check sees them."""
    return bool(crossing_faces(np.vstack([a, b]), np.array([[0, 1, 2], [3, 4, 5]])).all())


def test_each_rule_on_a_hand_made_pair():
    through = np.array([[0.2, 0.2, -1], [0.3, 0.2, 1], [0.2, 0.3, 1]])
    assert pair(TRI, through)                                       # one pierces the other
    assert not pair(TRI, through + [5, 0, 0])                       # the same, apart
    assert not pair(TRI, TRI + [0, 0, 1e-9])                        # parallel, just apart
    assert pair(TRI, np.array([[0.2, 0.2, 0], [0.3, 0.2, 1], [0.2, 0.3, 1]]))   # a vertex on the face: touching counts
    assert pair(TRI, TRI * 0.5 + [0.1, 0.1, 0])                     # coplanar, one inside the other
    assert pair(TRI, TRI + [0.5, 0.2, 0])                           # coplanar, edges crossing
    assert not pair(TRI, TRI + [1.5, 0, 0])                         # coplanar, apart
    assert not pair(TRI, np.array([[0.2, 0.2, 0], [0.2, 0.2, 0], [0.2, 0.2, 0]]))   # no area


def test_small_and_bad_inputs():
    assert crossing_faces(TRI, np.zeros((0, 3), np.int64)).shape == (0,)
    assert not crossing_faces(TRI, np.array([[0, 1, 2]])).any()
    with pytest.raises(ValueError, match="finite"):
        crossing_faces(np.vstack([TRI, [[np.nan, 0, 0], [1, 1, 1], [2, 2, 2]]]), np.array([[0, 1, 2], [3, 4, 5]]))


def test_faces_on_common_vertices():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0.2, 0.2, 3], [0.3, 0.3, -1], [1, 1, 1], [0.5, -1, 0.5]])
    assert crossing_faces(v, np.array([[0, 1, 2], [0, 3, 4]])).all()       # one vertex; the other's far edge pierces
    assert not crossing_faces(v, np.array([[0, 1, 2], [0, 5, 3]])).any()   # one vertex, otherwise apart
    assert not crossing_faces(v, np.array([[0, 1, 2], [1, 0, 6]])).any()   # an edge: neighbours never count
    assert crossing_faces(v, np.array([[0, 1, 2], [2, 1, 0]])).all()       # the same three vertices


def test_a_closed_mesh_has_none_and_a_face_pushed_through_is_found():
    sphere = trimesh.creation.icosphere(3)
    v, f = np.asarray(sphere.vertices).copy(), np.asarray(sphere.faces)
    assert not crossing_faces(v, f).any()
    assert not crossing_faces(*_two_boxes(0.01)).any()                    # two boxes close, apart
    assert crossing_faces(*_two_boxes(-0.01)).sum() >= 4                  # overlapping by a little
    top = np.argmax(v[:, 2])
    v[top] *= -0.5                                                         # a dimple: inside, crossing nothing
    assert not crossing_faces(v, f).any()
    v[top] *= 2.4                                                          # the north pole out through the south
    bad = crossing_faces(v, f)
    around, south = np.isin(f, top).any(1), v[f][:, :, 2].max(1) < -0.9
    assert bad[around].any() and bad[south].any() and not bad[~around & ~south].any()


def _two_boxes(gap: float) -> tuple[np.ndarray, np.ndarray]:
    a = trimesh.creation.box()
    b = trimesh.creation.box()
    b.apply_translation([1 + gap, 0.3, 0.2])
    m = trimesh.util.concatenate([a, b])
    return np.asarray(m.vertices), np.asarray(m.faces)


def test_the_narrow_test_agrees_with_edges_against_triangles_on_random_pairs():
    """Two triangles in general position meet exactly where an edge of one meets the other."""
    rng = np.random.default_rng(0)
    found = found_shared = 0
    for _ in range(3000):
        p = rng.random((6, 3))
        expected = any(_edge_meets(p[a], p[b], p[3:]) for a, b in ((0, 1), (1, 2), (2, 0))) or \
            any(_edge_meets(p[3 + a], p[3 + b], p[:3]) for a, b in ((0, 1), (1, 2), (2, 0)))
        assert _faces_cross(p, np.array([[0, 1, 2], [3, 4, 5]]), 0, 1) == expected
        found += expected
        shared = _edge_meets(p[1], p[2], p[[0, 3, 4]]) or _edge_meets(p[3], p[4], p[:3])    # on vertex 0
        assert _faces_cross(p, np.array([[0, 1, 2], [0, 3, 4]]), 0, 1) == shared
        found_shared += shared
    assert 300 < found < 2700 and 100 < found_shared < 2900               # both answers were tested often


def _edge_meets(s0: np.ndarray, s1: np.ndarray, tri: np.ndarray) -> bool:
    """The segment meets the triangle: the signed volumes' signs (Shewchuk's orientation form)."""
    def vol(a, b, c, d):
        return np.dot(np.cross(b - a, c - a), d - a)
    a, b, c = tri
    if vol(a, b, c, s0) * vol(a, b, c, s1) > 0:
        return False
    s = [vol(s0, s1, a, b), vol(s0, s1, b, c), vol(s0, s1, c, a)]
    return all(x >= 0 for x in s) or all(x <= 0 for x in s)


@pytest.mark.parametrize("seed", range(3))
def test_the_grid_finds_what_every_pair_finds(seed):
    rng = np.random.default_rng(seed)
    n = 300
    centre = rng.random((n, 3))
    size = np.where(rng.random(n) < 0.1, 0.3, 0.04)[:, None, None]     # a few large faces across many cells
    v = (centre[:, None] + size * (rng.random((n, 3, 3)) - 0.5)).reshape(-1, 3)
    faces = np.arange(3 * n).reshape(n, 3)
    faces[1::7, 0] = faces[::7, 0][: len(faces[1::7])]                    # some faces share a vertex
    brute = np.zeros(n, bool)
    for f, g in itertools.combinations(range(n), 2):
        if _faces_cross(v, faces, f, g):
            brute[f] = brute[g] = True
    got = crossing_faces(v, faces)
    assert brute.sum() > 20 and np.array_equal(got, brute)


def test_a_few_huge_faces_beside_many_small_ones_keep_the_grid_small():
    rng = np.random.default_rng(3)
    small = (rng.random((4000, 1, 3)) + 0.004 * rng.random((4000, 3, 3))).reshape(-1, 3)
    huge = np.array([[-5.0, -5, 0.5], [5, -5, 0.5], [0, 5, 0.5]] * 20) + np.repeat(np.arange(20), 3)[:, None] * [0, 0, 1e-3]
    v = np.vstack([small, huge])
    faces = np.arange(len(v)).reshape(-1, 3)
    got = crossing_faces(v, faces)
    assert got[4000:].all()                                   # the huge faces cross the small ones near z = 0.5
    lo, hi = v[faces].min(1), v[faces].max(1)
    near = (lo[:4000, 2] <= 0.52) & (hi[:4000, 2] >= 0.5)
    alone = crossing_faces(small, faces[:4000])
    assert np.array_equal(got[:4000] & ~near, alone & ~near)   # away from the plane: the small faces' own crossings
