"""The decode loop grows exactly the octree its predictions describe."""

import numpy as np
import pytest

from model.decode import decode, full_levels
from model.octree import EMPTY, build_octree
from model.octree.batch import merge_octrees
from model.octree.keys import child_keys

from ..octree.conftest import sphere_points
from ..octree.test_tables import neighbors_by_key_search


class OracleSteps:
    """Predicts a given octree's labels and planes; its 'features' are the octants' keys."""

    def __init__(self, truth, three_class_from=4):
        self.truth, self.depth, self.three = truth, truth.depth, three_class_from

    def classes(self, depth):
        return 3 if depth >= self.three else 2

    def start(self, latent):
        return self.truth.levels[2].key[: 64 * len(latent)]

    def predict(self, depth, keys, neighbors):
        lv = self.truth.levels[depth]
        pos = np.searchsorted(lv.key, keys)
        assert np.array_equal(lv.key[pos], keys)
        label = lv.label[pos]
        if self.classes(depth) == 2:
            status = (label != EMPTY).astype(int)
        else:
            status = np.choose(label, [0, 1, 2])
        return keys, np.eye(self.classes(depth))[status], lv.plane[pos]

    def expand(self, depth, keys, split):
        return child_keys(keys[split])


@pytest.mark.parametrize("adaptive", [True, False])
def test_decoding_its_own_predictions_reproduces_the_octree(adaptive):
    shapes = [sphere_points(20_000), (sphere_points(20_000)[0] * [1, 0.3, 1], sphere_points(20_000)[1])]
    truth = merge_octrees([build_octree(s, 6, adaptive=adaptive) for s in shapes])
    out = decode(OracleSteps(truth, 4 if adaptive else 99), np.zeros((2, 8)))
    assert out.batch_size == 2 and out.depth == 6
    for a, b in zip(truth.levels, out.levels):
        assert np.array_equal(a.key, b.key)
        assert np.array_equal(a.label, b.label)
        assert np.array_equal(a.child, b.child)
        assert np.array_equal(a.parent, b.parent)
        assert np.array_equal(a.neighbors, b.neighbors)
        if a.depth >= 2:                  # the decoder predicts from the full depth 2 on
            assert np.allclose(a.plane, b.plane)


def test_full_levels_and_early_stop():
    lv = full_levels(3)
    assert [len(x) for x in lv] == [3, 24, 192]
    assert np.array_equal(lv[2].neighbors, neighbors_by_key_search(lv[2]))

    class Nothing(OracleSteps):
        def predict(self, depth, keys, neighbors):
            return keys, np.eye(2)[np.zeros(len(keys), int)], None

    pts, nrm = sphere_points(5000)
    out = decode(Nothing(build_octree((pts, nrm), 5)), np.zeros((1, 8)))
    assert [len(x) for x in out.levels] == [1, 8, 64, 0, 0, 0]
    assert np.all(out.levels[2].label == EMPTY)
