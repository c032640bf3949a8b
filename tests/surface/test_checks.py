"""The closedness and manifoldness checks, against hand-made meshes and trimesh's own."""

from collections import Counter

import numpy as np
import trimesh

from model.surface.checks import WELD, edge_faults, fan_counts, is_closed, is_closed_embedded, is_manifold, weld

TETRA = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]])


def test_a_tetrahedron_is_closed_and_every_way_of_breaking_it_is_caught():
    assert is_closed(TETRA) and is_manifold(TETRA)
    assert not is_closed(TETRA[:3])                                # a hole
    flipped = TETRA.copy()
    flipped[0] = flipped[0, ::-1]
    assert not is_closed(flipped)                                  # one face wound the other way
    assert not is_closed(np.vstack([TETRA, TETRA[:1]]))            # a face twice
    assert not is_closed(np.vstack([TETRA, TETRA[:1, ::-1]]))      # a face and its back: three faces on its edges
    assert not is_closed(np.array([[0, 0, 1], [1, 0, 0]]))         # degenerate edges
    assert is_closed(np.zeros((0, 3), np.int64))
    assert not is_closed(np.vstack([TETRA, [[4, 5, 6]]]))           # a lone triangle beside it
    assert not is_closed(np.array([[0, 1, 2], [0, 2, 3]]))          # a fan: its outer vertices in one face
    assert is_closed(np.array([[0, 1, 2], [0, 2, 1]]))              # two faces back to back: closed, each vertex in two


def test_two_tetrahedra_on_one_vertex_are_closed_but_not_a_manifold():
    pinched = np.vstack([TETRA, TETRA + 3])                        # vertex 3 shared
    assert is_closed(pinched) and not is_manifold(pinched)
    apart = np.vstack([TETRA, TETRA + 4])
    assert is_closed(apart) and is_manifold(apart)


def test_agrees_with_trimesh_on_closed_meshes_and_on_their_damaged_copies():
    rng = np.random.default_rng(0)
    for mesh in (trimesh.creation.icosphere(2), trimesh.creation.torus(1.0, 0.3), trimesh.creation.box()):
        faces = np.asarray(mesh.faces)
        assert is_closed(faces) and is_manifold(faces)
        for _ in range(5):
            damaged = faces.copy()
            i = rng.integers(len(faces))
            if rng.random() < 0.5:
                damaged = np.delete(damaged, i, axis=0)
            else:
                damaged[i] = damaged[i, ::-1]
            t = trimesh.Trimesh(mesh.vertices, damaged, process=False)
            assert not (t.is_watertight and t.is_winding_consistent)
            assert not is_closed(damaged)


def test_a_welding_reader_sees_vertices_at_one_position_as_one():
    """Two tetrahedra touching at a corner, each with its own vertex there: closed and a manifold in
    the index buffer, pinched once welded; moved apart by a little more than WELD of the box, not."""
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    other = 2 * corners[3] - corners                                # mirrored through the first's vertex 3
    faces = np.vstack([TETRA, TETRA + 4])
    touching = np.vstack([corners, other])
    assert is_closed(faces) and is_manifold(faces)
    assert np.array_equal(touching[3], touching[7])
    welded = weld(touching, faces)
    assert len(np.unique(welded)) == 7 and not is_closed_embedded(touching, faces)
    diag = np.linalg.norm(touching.max(0) - touching.min(0))
    apart = touching.copy()
    apart[7] += 3 * WELD * diag
    assert is_closed_embedded(apart, faces)
    close = touching.copy()
    close[7] += 0.3 * WELD * diag
    assert not is_closed_embedded(close, faces)


def test_a_weld_that_collapses_a_face_is_not_closed():
    corners = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
    squashed = corners.copy()
    squashed[1] = squashed[0] + 1e-9                                # an edge shorter than the weld
    assert is_closed(TETRA) and is_closed_embedded(corners, TETRA) and not is_closed_embedded(squashed, TETRA)


def _edge_faults_by_counting(faces: np.ndarray) -> np.ndarray:
    """The reference: count every directed edge in a dictionary."""
    count = Counter(zip(faces.ravel().tolist(), np.roll(faces, -1, axis=1).ravel().tolist()))
    return np.array([not (count[(a, b)] == 1 and count[(b, a)] == 1)
                     for a, b in zip(faces.ravel().tolist(), np.roll(faces, -1, axis=1).ravel().tolist())])


def _fans_by_walking(faces: np.ndarray, v: int) -> int:
    """The reference: the faces at ``v`` walked across their shared edges (w -> v to v -> w)."""
    around = [f for f in faces.tolist() if v in f]
    pairs = [(f[(f.index(v) + 1) % 3], f[(f.index(v) + 2) % 3]) for f in around]     # (next, previous)
    fans, seen = 0, set()
    for start in range(len(pairs)):
        if start in seen:
            continue
        fans += 1
        todo = [start]
        while todo:
            i = todo.pop()
            if i not in seen:
                seen.add(i)
                todo += [j for j in range(len(pairs)) if pairs[i][0] == pairs[j][1] or pairs[j][0] == pairs[i][1]]
    return fans


def test_edge_faults_and_fans_agree_with_counting_and_walking_on_damaged_and_pinched_meshes():
    rng = np.random.default_rng(3)
    sphere = np.asarray(trimesh.creation.icosphere(1).faces)
    pinched = np.vstack([sphere, np.where(sphere == 0, 0, sphere + sphere.max() + 1)])   # two spheres at vertex 0
    for faces in (sphere, pinched, sphere[rng.random(len(sphere)) < 0.9], np.vstack([sphere, sphere[:3, ::-1]]),
                  np.vstack([sphere, sphere[:4]])):
        n = int(faces.max()) + 1
        wrong = edge_faults(faces, n)
        assert np.array_equal(wrong, _edge_faults_by_counting(faces))
        sound = np.ones(n, bool)
        sound[faces.ravel()[wrong]] = False
        sound[np.roll(faces, -1, axis=1).ravel()[wrong]] = False
        fans = fan_counts(faces, n)
        for v in np.flatnonzero(sound):
            assert fans[v] == _fans_by_walking(faces, v), v
    counts, used = fan_counts(pinched), np.bincount(pinched.ravel()) > 0
    assert counts[0] == 2 and (counts[1:][used[1:]] == 1).all() and (counts[~used] == 0).all()
    assert fan_counts(sphere, sphere.max() + 3)[-2:].tolist() == [0, 0]           # vertices no face uses
