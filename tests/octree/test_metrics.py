"""Distances between point sets used by the evaluations."""

import numpy as np
import pytest


def test_missing_distance_measures_only_what_the_scan_lacks():
    from model.octree.metrics import missing_distance

    t = np.linspace(0, 1, 201)
    truth = np.c_[t, np.zeros_like(t), np.zeros_like(t)]           # a segment of length 1
    seen = truth[t <= 0.5]                                          # its left half was scanned
    assert missing_distance(truth, truth, truth, 0.0125) is None       # nothing missing
    far = truth[t > 0.5125]
    # the scan itself: each missing point's distance to x = 0.5, squared, averaged
    assert missing_distance(truth, seen, seen, 0.0125) == pytest.approx(((far[:, 0] - 0.5) ** 2).mean())
    assert missing_distance(truth, seen, truth, 0.0125) == 0.0         # a perfect completion
    shifted = truth + [0, 0.1, 0]
    assert missing_distance(truth, seen, shifted, 0.0125) == pytest.approx(0.01)


def test_a_reference_measures_chamfer_and_f_score_from_one_pair_of_queries():
    from model.octree.metrics import Reference, mean_squared_distance

    # a unit square's corners against the same corners, one moved by 0.3 and one extra point 2 away
    ref = Reference(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]], float))
    pts = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0.3], [1, 1, 2.0]])
    near = ref.nearest(pts)
    assert np.allclose(near.to_points, [0, 0, 0, 0.3]) and list(near.to_index) == [0, 1, 2, 3]
    assert np.allclose(near.from_points, [0, 0, 0, 0.3, 2.0]) and list(near.from_index) == [0, 1, 2, 3, 3]
    assert near.chamfer() == pytest.approx(0.09 / 4 + (0.09 + 4.0) / 5)
    # at 0.1: precision 3 of 5, recall 3 of 4; at 0.5: 4 of 5 and 4 of 4
    assert near.fscore(0.1) == pytest.approx(2 * 0.6 * 0.75 / 1.35)
    assert near.fscore(0.5) == pytest.approx(2 * 0.8 / 1.8)
    assert ref.nearest(pts + 10).fscore(0.5) == 0.0

    # the same figure as the two one-way distances, to the bit, on random sets
    rng = np.random.default_rng(0)
    truth, pred = rng.random((3000, 3)), rng.random((2000, 3)) * 1.1
    assert Reference(truth).chamfer(pred) == mean_squared_distance(truth, pred) + mean_squared_distance(pred, truth)
    with pytest.raises(ValueError, match="non-empty"):
        ref.nearest(np.zeros((0, 3)))
