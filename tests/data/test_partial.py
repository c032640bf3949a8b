"""Partial scans: strict subsets of the complete scan, with holes and noise."""

import numpy as np

from model.data.partial import partial_from_scan, partial_indices, partial_scan
from model.data.scanner import scan_detailed
from model.data.shapes import generate


def test_partial_is_strict_subset_with_holes():
    full = scan_detailed(generate("car", 0), resolution=64)
    rng = np.random.default_rng(3)
    for _ in range(5):
        idx, holes = partial_indices(full, rng)
        views = np.unique(full.view[idx])
        assert 3 <= len(views) <= 5
        assert len(np.unique(idx)) == len(idx) < len(full.points)
        assert 1 * len(views) <= len(holes) <= 3 * len(views)
        for v, centre, r in holes:
            assert r > 0
            mine = idx[full.view[idx] == v]
            assert (np.linalg.norm(full.uv[mine] - centre, axis=1) >= r - 1e-6).all()
            # The hole removed something: the complete view had points there.
            in_view = full.view == v
            assert (np.linalg.norm(full.uv[in_view] - centre, axis=1) < r).sum() > 0
        # Fewer points than the chosen views hold in the complete scan.
        assert len(idx) < np.isin(full.view, views).sum()


def test_noise_is_small_and_points_match_subset():
    full = scan_detailed(generate("car", 1), resolution=64)
    p0, n0, idx0 = partial_from_scan(full, np.random.default_rng(5), noise=0.0)
    np.testing.assert_array_equal(p0, full.points[idx0])
    np.testing.assert_array_equal(n0, full.normals[idx0])
    p1, _, idx1 = partial_from_scan(full, np.random.default_rng(5), noise=0.005)
    np.testing.assert_array_equal(idx0, idx1)
    d = np.linalg.norm(p1 - full.points[idx1], axis=1)
    sigma = 0.005 * 2 * full.radius
    assert 0.5 * sigma < np.sqrt((d**2).mean() / 3) < 2 * sigma


def test_partial_scan_api():
    pts, nrm = partial_scan(generate("car", 2), np.random.default_rng(0), resolution=48)
    assert pts.dtype == np.float32 and nrm.shape == pts.shape and len(pts) > 1000
