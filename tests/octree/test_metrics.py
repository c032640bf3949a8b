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
