"""The compiled graph helpers against SciPy: connected parts numbered alike, close pairs alike."""

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from model.surface.graph import close_pairs, components


def test_components_are_numbered_as_scipy_numbers_them():
    rng = np.random.default_rng(5)
    for n, m in ((1, 0), (50, 10), (2000, 1500), (2000, 4000)):
        a, b = rng.integers(0, n, m), rng.integers(0, n, m)
        graph = coo_matrix((np.ones(m, np.int8), (a, b)), shape=(n, n))
        assert np.array_equal(components(n, a, b), connected_components(graph, directed=False)[1])


def _pairs(p: np.ndarray) -> set:
    return set(map(tuple, np.sort(p, axis=1).tolist()))


def test_close_pairs_are_the_k_d_trees_on_coincident_near_and_far_points():
    rng = np.random.default_rng(2)
    base = rng.random((3000, 3))
    r = 1e-6
    twins = base[:200] + rng.normal(scale=0.3 * r, size=(200, 3))            # within the radius
    just_out = base[200:300] + np.array([1.5 * r, 0, 0])                      # just beyond it
    on_sides = np.floor(base[300:400] / (1024 * r)) * (1024 * r)               # on the hash grid's cell sides
    points = np.vstack([base, twins, just_out, on_sides, on_sides + np.array([0, 0.5 * r, 0]), base[:5]])
    want = _pairs(cKDTree(points).query_pairs(r, output_type="ndarray"))
    got = close_pairs(points, r)
    assert len(got) == len(want) and _pairs(got) == want and (got[:, 0] < got[:, 1]).all()
    assert len(want) >= 300                                                     # twins, sides and copies: pairs to find
    assert len(close_pairs(points, 0.0)) == 0 and len(close_pairs(points[:1], r)) == 0
    huge = np.vstack([points, [[1e30, 0, 0]]])                                 # beyond 64-bit cells: the k-d tree
    assert _pairs(close_pairs(huge, r)) == want
