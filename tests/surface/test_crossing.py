"""Faces that cross other faces: hand-made pairs for each rule, the narrow test against an
independent formulation on random triangles, and the grid's candidate pairs against every pair."""

import itertools
from fractions import Fraction

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


def test_the_pair_test_is_the_exact_rule_on_small_integer_coordinates():
    """Coordinates 0..2: touching, coplanar and degenerate pairs are frequent, and the rule's
    arithmetic is exact there, so it must agree with an exact formulation (fractions) pair by pair."""
    rng = np.random.default_rng(5)
    kinds = {"cross": 0, "apart": 0}
    for shared in (0, 1):
        for _ in range(1500):
            v = rng.integers(0, 3, (6, 3)).astype(float)
            if rng.random() < 0.3:
                v[:, 2] = 0.0                                        # coplanar pairs
            faces = np.array([[0, 1, 2], [3, 4, 5]] if shared == 0 else [[0, 1, 2], [0, 4, 5]])
            got = bool(_faces_cross(v, faces, 0, 1))
            assert got == _exact_cross(v, faces), (v.tolist(), faces.tolist())
            kinds["cross" if got else "apart"] += 1
    assert min(kinds.values()) > 300


def test_degenerate_faces_never_count_and_scale_does_not_matter():
    v = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    assert not crossing_faces(v, np.array([[0, 0, 1], [0, 1, 2]])).any()        # a repeated index
    needle = np.array([[-1, 0, 0], [1, 0, 0], [0, 0, 0], [0, 1, 1], [0, -1, 1.0]])
    assert not crossing_faces(needle, np.array([[0, 1, 2], [2, 3, 4]])).any()    # no area, its edge through a vertex
    pierced = np.array([[0, 0, 0], [4, 0, 0], [0, 4, 0], [1, 1, -1], [1, 1, 1], [2, 1, 0.0]])
    apart = pierced.copy()
    apart[3:] += [4, 4, 0]
    faces = np.array([[0, 1, 2], [3, 4, 5]])
    for scale in (2.0 ** -85, 1e-300, 1.0, 2.0 ** 80, 1e300):           # products of 13 coordinates would not fit
        assert crossing_faces(pierced * scale, faces).all() and not crossing_faces(apart * scale, faces).any()
    tri = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0.0]])
    assert not crossing_faces(np.vstack([tri - 1.5e308, tri + 1.5e308]), faces).any()   # its span overflows
    nearly = np.array([[0, 0, 0], [10, 0, 0], [0, 10, 0], [8, 8, 1e-90], [9, 8, -1e-90], [8, 9, 1e-90]])
    assert not crossing_faces(nearly, faces).any()                   # nearly coplanar, 4 apart in the plane


def test_a_flat_region_and_one_far_face_are_tested_as_every_pair_would_be():
    n = 24
    ys, zs = np.meshgrid(np.arange(n), np.arange(n))
    flat = np.stack([np.zeros(n * n), ys.ravel(), zs.ravel()], 1).astype(float)
    i = np.arange(n * n).reshape(n, n)
    faces = np.concatenate([np.stack([i[:-1, :-1].ravel(), i[1:, :-1].ravel(), i[1:, 1:].ravel()], 1),
                            np.stack([i[:-1, :-1].ravel(), i[1:, 1:].ravel(), i[:-1, 1:].ravel()], 1)])
    v = np.vstack([flat, [[1000, 0, 0], [1001, 0, 0], [1000, 1, 0.0]], [[0.0, 3.5, -1], [0.0, 3.5, 30], [0.0, 4.5, 3]],
                   [[0.0, 10.2, 10.2], [0.0, 10.8, 10.2], [0.0, 10.2, 10.8]]])
    m = n * n                                                   # + one far face, one large, one lying on the flat ones
    faces = np.vstack([faces, [[m, m + 1, m + 2], [m + 3, m + 4, m + 5], [m + 6, m + 7, m + 8]]])
    brute = np.zeros(len(faces), bool)
    for f, g in itertools.combinations(range(len(faces)), 2):
        if _faces_cross(v, faces, f, g):
            brute[f] = brute[g] = True
    got = crossing_faces(v, faces)
    assert got[-1] and brute.sum() > 10 and np.array_equal(got, brute)


def _exact_cross(v: np.ndarray, faces: np.ndarray) -> bool:
    """The module's rule for faces 0 and 1, in exact rational arithmetic."""
    p = [tuple(Fraction(x) for x in v[i]) for i in faces[0]]
    q = [tuple(Fraction(x) for x in v[i]) for i in faces[1]]
    if _normal3(*p) == (0, 0, 0) or _normal3(*q) == (0, 0, 0):
        return False
    common = set(faces[0].tolist()) & set(faces[1].tolist())
    if len(common) == 3:
        return True
    if len(common) == 2:
        return False
    if not common:
        return any(_segment_meets_exact(p[k], p[(k + 1) % 3], q, True) or
                   _segment_meets_exact(q[k], q[(k + 1) % 3], p, True) for k in range(3))
    s = common.pop()
    a, b = faces[0].tolist().index(s), faces[1].tolist().index(s)
    return _segment_meets_exact(p[(a + 1) % 3], p[(a + 2) % 3], q, False) or \
        _segment_meets_exact(q[(b + 1) % 3], q[(b + 2) % 3], p, False)


def _sub3(a, b):
    return tuple(x - y for x, y in zip(a, b))


def _normal3(a, b, c):
    u, w = _sub3(b, a), _sub3(c, a)
    return (u[1] * w[2] - u[2] * w[1], u[2] * w[0] - u[0] * w[2], u[0] * w[1] - u[1] * w[0])


def _segment_meets_exact(s0, s1, tri, in_plane: bool) -> bool:
    """The closed segment meets the closed triangle; a segment in the triangle's plane counts only
    when ``in_plane`` (two triangles' edges in their common plane)."""
    n = _normal3(*tri)
    d0, d1 = (sum(x * y for x, y in zip(n, _sub3(s, tri[0]))) for s in (s0, s1))
    keep = [k for k in range(3) if k != max(range(3), key=lambda k: abs(n[k]))]
    flat = [tuple(p[k] for k in keep) for p in (s0, s1, *tri)]
    if d0 == 0 and d1 == 0:
        if not in_plane:
            return False
        a, b, t0, t1, t2 = flat
        return _inside(a, t0, t1, t2) or _inside(b, t0, t1, t2) or \
            any(_segments_meet(a, b, x, y) for x, y in ((t0, t1), (t1, t2), (t2, t0)))
    if (d0 > 0 and d1 > 0) or (d0 < 0 and d1 < 0):
        return False
    t = d0 / (d0 - d1)
    hit = tuple(x + t * (y - x) for x, y in zip(flat[0], flat[1]))
    return _inside(hit, *flat[2:])


def _orient(a, b, c):
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


def _inside(p, a, b, c) -> bool:
    s = (_orient(a, b, p), _orient(b, c, p), _orient(c, a, p))
    return all(x >= 0 for x in s) or all(x <= 0 for x in s)


def _segments_meet(a, b, c, d) -> bool:
    def on(p, x, y):
        return _orient(x, y, p) == 0 and min(x[0], y[0]) <= p[0] <= max(x[0], y[0]) and \
            min(x[1], y[1]) <= p[1] <= max(x[1], y[1])
    o1, o2, o3, o4 = _orient(a, b, c), _orient(a, b, d), _orient(c, d, a), _orient(c, d, b)
    if o1 * o2 < 0 and o3 * o4 < 0:
        return True
    return on(c, a, b) or on(d, a, b) or on(a, c, d) or on(b, c, d)
