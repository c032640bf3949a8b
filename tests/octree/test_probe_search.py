"""patch->surface on the plane grid (model.octree.probe_search): the k-d tree's values, bit for bit."""

from __future__ import annotations

import numpy as np
import pytest

from model.octree import patch_error
from model.octree.geometry import plane_basis
from model.octree.patch_error import PatchErrorSettings, patch_errors


def random_patches(seed: int, t_count: int = 80, size: float = 1.0 / 16):
    """Octants of one size in a row along x, each with a random plane and points near it (some
    octants dense, some sparse, some with a hole), as build rows (3, N) sorted by octant."""
    rng = np.random.default_rng(seed)
    normal = rng.normal(size=(t_count, 3))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    offset = rng.uniform(-0.2, 0.2, t_count) * size
    centre = np.stack([(np.arange(t_count) % 16 + 0.5) * size, np.full(t_count, 0.5), np.full(t_count, 0.5)], 1)
    u, v = plane_basis(normal)
    pts = []
    count = []
    for t in range(t_count):
        n = int(rng.integers(3, 600))
        a, b = rng.uniform(-0.9, 0.9, (2, n)) * size
        h = rng.normal(0, 0.02, n) * size
        p = -offset[t] * normal[t] + a[:, None] * u[t] + b[:, None] * v[t] + h[:, None] * normal[t]
        if t % 5 == 0:                                   # a hole in the patch
            p = p[np.hypot(a, b) > 0.4 * size]
        p = p[(np.abs(p) < size / 2).all(1)]
        if len(p) == 0:
            p = np.zeros((1, 3))
        pts.append(p + centre[t])
        count.append(len(p))
    count = np.array(count)
    return np.concatenate(pts).T.copy(), centre, normal, offset, np.cumsum(count) - count, count


@pytest.mark.parametrize("seed, exact", [(0, False), (1, True), (2, False)])
def test_the_plane_grid_search_reads_what_the_k_d_tree_reads(seed, exact):
    pts, centre, normal, offset, start, count = random_patches(seed)
    nrm = np.repeat(normal.T, count, axis=1)
    size = 1.0 / 16
    cfg = PatchErrorSettings(threshold=0.15 * size, gap=0.03 * size, probe_spacing=size / 12)
    args = (pts, nrm, cfg, centre, normal, offset, size, start, count)
    searched = patch_errors(*args, exact=exact)
    tree = patch_errors(*args, exact=exact, probe_search=False)
    assert np.array_equal(searched, tree)
    # every path is taken: probes read zero, positive, and (with a bound) infinite
    assert (searched > 0).any() and np.isfinite(searched).any()
    if not exact:
        assert np.isinf(searched).any()


def test_the_probes_decide_these_cases(monkeypatch):
    """Without the probes' distances (all read zero) the errors differ: the equality above is
    about the probe search, not about the surface->patch half alone."""
    pts, centre, normal, offset, start, count = random_patches(0)
    nrm = np.repeat(normal.T, count, axis=1)
    size = 1.0 / 16
    cfg = PatchErrorSettings(threshold=0.15 * size, gap=0.03 * size, probe_spacing=size / 12)
    args = (pts, nrm, cfg, centre, normal, offset, size, start, count)
    tree = patch_errors(*args, exact=True, probe_search=False)
    real = patch_error.probe_errors

    def zeros(*a, **k):
        grid, edge = real(*a, **k)
        return np.zeros_like(grid), np.zeros_like(edge)

    monkeypatch.setattr(patch_error, "probe_errors", zeros)
    blind = patch_errors(*args, exact=True)
    assert (blind < tree).sum() >= 10
