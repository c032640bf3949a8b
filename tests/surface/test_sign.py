"""Inside and outside of the grid's corners: which flood is kept, and a leak through a hole in the
predicted surface closed while the slots between thin parts stay open."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from model.octree import LEAF, build_octree
from model.surface import watertight_mesh
from model.surface.sign import chosen_seal

from ..octree.conftest import sphere_points


@pytest.mark.parametrize("shares, seal", [
    ([0.05], 0),                          # no leak: the first seal
    ([0.43, 0.30, 0.12, 0.0], 2),         # a leak closed by the third seal
    ([0.60, 0.28, 0.25, 0.22], 1),        # never under LEAK, but the second halves the share: a leak
    ([0.54, 0.55, 0.55, 0.54], 0),        # flat: thin parts' backs, not a leak
    ([0.47, 0.45, 0.43, 0.28], 0),        # falling, not halving
])
def test_the_seal_kept_is_the_first_that_stops_a_leak_and_no_wider_for_thin_parts(shares, seal):
    assert chosen_seal(shares) == seal


def test_a_hole_in_the_predicted_surface_does_not_let_the_outside_in():
    """A sphere whose leaves within two cells of its top are predicted empty (a hole four cells
    wide: the first seal's flood leaks in, the second's does not): still one solid of the whole
    sphere's volume, not a shell."""
    depth, h = 5, 1.0 / 32
    whole = watertight_mesh(build_octree(sphere_points(60_000), depth, neighbors=False), world=False)
    o = build_octree(sphere_points(60_000), depth, neighbors=False)
    removed = 0
    for lv in o.levels:
        c = lv.centers()
        hole = (c[:, 1] > 0.5) & (np.hypot(c[:, 0] - 0.5, c[:, 2] - 0.5) < 2 * h) & (lv.label == LEAF)
        removed += int(hole.sum())
        lv.label[hole] = 0
    m = watertight_mesh(o, world=False)
    mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
    assert removed >= 4 and m.closed and mesh.body_count == 1
    assert mesh.volume == pytest.approx(trimesh.Trimesh(whole.vertices, whole.faces, process=False).volume, rel=0.05)
