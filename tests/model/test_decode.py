"""The decode loop grows exactly the octree its predictions describe."""

import numpy as np
import pytest

from model.decode import Guide, decode, full_levels
from model.octree import EMPTY, build_octree
from model.octree.batch import merge_octrees, split_octree
from model.octree.keys import batch_of, child_keys, with_batch

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


def test_split_predicted_at_the_max_depth_becomes_a_leaf():
    """A 3-class decoder that predicts 'split' everywhere: the last depth's octants are leaves with
    their patches (without the rule every one of them would vanish from the mesh)."""
    from model.octree import LEAF, SPLIT
    from model.octree.patches import patches_to_mesh

    class AlwaysSplit:
        depth = 4

        def classes(self, depth):
            return 3 if depth >= 3 else 2

        def start(self, latent):
            return np.zeros((64 * len(latent), 1))

        def predict(self, depth, x, neighbors):
            k = self.classes(depth)
            logits = np.tile(np.eye(k)[1], (len(x), 1))          # non-empty / split everywhere
            planes = np.tile([0.0, 0.0, 1.0, 0.0], (len(x), 1)) if k == 3 else None
            return x, logits, planes

        def expand(self, depth, x, split):
            return np.zeros((8 * len(split), 1))

    out = decode(AlwaysSplit(), np.zeros((1, 8)), adaptive_depth=3)
    last = out.levels[-1]
    assert len(last) == 8 ** 4 and np.all(last.label == LEAF) and not np.any(last.label == SPLIT)
    assert np.all(out.levels[3].label == SPLIT)
    assert len(patches_to_mesh(out, world=False).faces) == 2 * 8 ** 4     # one square per leaf


def test_an_empty_bias_prunes_only_the_depths_it_is_given():
    """Logits are one-hot (1 for the true class): a bias above 1 on *empty* at depth 5 empties
    every depth-5 octant, keeps depths 2-4 as they were, and leaves depth 6 with nothing to grow."""
    pts, nrm = sphere_points(20_000)
    truth = build_octree((pts, nrm), 6)
    base = decode(OracleSteps(truth), np.zeros((1, 8)))
    same = decode(OracleSteps(truth), np.zeros((1, 8)), empty_bias={5: 0.0})
    assert all(np.array_equal(a.label, b.label) for a, b in zip(base.levels, same.levels))
    pruned = decode(OracleSteps(truth), np.zeros((1, 8)), empty_bias={5: 1.5})
    for d in range(5):
        assert np.array_equal(pruned.levels[d].label, base.levels[d].label)
    assert np.all(pruned.levels[5].label == EMPTY) and base.levels[5].nonempty.any()
    assert len(pruned.levels[6]) == 0
    half = decode(OracleSteps(truth), np.zeros((1, 8)), empty_bias={5: 0.5})     # below the margin: no change
    assert all(np.array_equal(a.label, b.label) for a, b in zip(base.levels, half.levels))


class GuidedOracleSteps(OracleSteps):
    """:class:`OracleSteps` that checks the rows the loop hands a guided decoder: the guide's
    'features' are its keys, so a found row must hold the grown octant's own position (the batch
    bits may differ: a subset renumbers the shapes, its features keep theirs)."""

    def __init__(self, truth):
        super().__init__(truth)
        self.found = {}

    def predict(self, depth, keys, neighbors, skip=None, skip_index=None):
        found = skip_index < len(skip)
        assert np.array_equal(with_batch(skip[skip_index[found]], 0), with_batch(keys[found], 0))
        self.found[depth] = int(found.sum())
        return super().predict(depth, keys, neighbors)


def test_a_guide_gives_each_grown_octant_its_input_octant_by_key_per_shape():
    pts, nrm = sphere_points(20_000)
    half = pts[:, 0] > 0.1                             # the scan saw one side of the sphere
    truth = merge_octrees([build_octree((pts, nrm), 6), build_octree((pts[::-1], nrm[::-1]), 6)])
    scan = merge_octrees([build_octree((pts[half], nrm[half]), 6, normalization=truth.normalizations[0]),
                          build_octree((pts, nrm), 6)])
    guide = Guide.of(scan, {d: scan.levels[d].key for d in range(2, 7)})
    steps = GuidedOracleSteps(truth)
    grown = decode(steps, np.zeros((2, 8)), guide=guide)
    assert [len(lv) for lv in grown.levels] == [len(lv) for lv in truth.levels]
    assert steps.found[2] == 128 and steps.found[6] == int(np.isin(scan.levels[6].key, truth.levels[6].key).sum())
    assert 0 < steps.found[6] < len(truth.levels[6])          # the half scan misses part of the first shape

    # the second shape alone, renumbered to position 0, finds what it found in the batch
    second = guide.subset(np.array([1]))
    only = GuidedOracleSteps(split_octree(truth, neighbors=True)[1])
    decode(only, np.zeros((1, 8)), guide=second)
    in_batch = np.isin(scan.levels[6].key[batch_of(scan.levels[6].key) == 1], truth.levels[6].key).sum()
    assert only.found[6] == in_batch > 0
    assert np.all(batch_of(second.keys[6]) == 0) and len(second.features[6]) == len(second.keys[6])
