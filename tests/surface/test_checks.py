"""The closedness and manifoldness checks, against hand-made meshes and trimesh's own."""

import numpy as np
import trimesh

from model.surface.checks import is_closed, is_manifold

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
