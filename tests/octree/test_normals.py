"""Normal estimation, compiled (model.octree.orient): the same normals bit for bit as the NumPy and
SciPy formulation it replaced (k-NN PCA, Kruskal's spanning tree by SciPy over the symmetric
graph, signs along the tree, each part flipped outward), on scans whose many tied weights make
the tree depend on the order ties are taken in."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

from model.data import generate, scan
from model.octree.orient import edges_by_weight, radix_order, sorted_payloads
from model.octree.pointcloud import estimate_normals

from .reference_planes import eigenvector, symmetric_eigen


def scipy_normals(points: np.ndarray, k: int = 16) -> np.ndarray:
    """The formulation before the compiled one (kept here as the reference)."""
    n = len(points)
    _, nn = cKDTree(points).query(points, k=k, workers=-1)
    nb = points[nn]
    d = nb - nb.mean(1)[:, None]
    cov = np.stack([(d[..., a] * d[..., b]).mean(1) for a, b in ((0, 0), (0, 1), (0, 2), (1, 1), (1, 2), (2, 2))])
    normals = eigenvector(cov, symmetric_eigen(cov)[2])
    rows, cols = np.repeat(np.arange(n), k - 1), nn[:, 1:].ravel()
    w = 1.0 - np.abs((normals[rows] * normals[cols]).sum(1)) + 1e-6
    graph = sparse.coo_matrix((w, (rows, cols)), shape=(n, n)).tocsr()
    mst = csgraph.minimum_spanning_tree(graph.maximum(graph.T))
    mst = (mst + mst.T).tocoo()
    parts, comp = csgraph.connected_components(mst, directed=False)
    roots = np.unique(comp, return_index=True)[1]
    r = np.r_[mst.row, np.full(len(roots), n), roots]
    c = np.r_[mst.col, roots, np.full(len(roots), n)]
    joined = sparse.coo_matrix((np.ones(len(r)), (r, c)), shape=(n + 1, n + 1)).tocsr()
    _, pred = csgraph.breadth_first_order(joined, n, directed=False, return_predecessors=True)
    pred = pred[:n].copy()
    pred[roots] = roots
    sign = np.where((normals * normals[pred]).sum(1) < 0, -1.0, 1.0)
    hop = pred.copy()
    sign[pred == np.arange(n)] = 1.0
    while True:
        sign = sign * sign[hop]
        nxt = hop[hop]
        if np.array_equal(nxt, hop):
            break
        hop = nxt
    normals = normals * sign[:, None]
    count = np.bincount(comp, minlength=parts)
    centroid = np.stack([np.bincount(comp, points[:, a], parts) for a in range(3)], 1) / count[:, None]
    flip = np.bincount(comp, np.sign(((points - centroid[comp]) * normals).sum(1)), parts) < 0
    normals[flip[comp]] *= -1.0
    return normals


@pytest.mark.parametrize("category, index", [("lamp", 3), ("chair", 9002), ("airplane", 7), ("table", 5)])
def test_the_normals_are_the_scipy_formulation_s_bit_for_bit(category, index):
    points = scan(generate(category, index), resolution=128)[0][::2].astype(np.float64)   # as validate gives them
    ours, theirs = estimate_normals(points), scipy_normals(points)
    assert np.array_equal(ours, theirs)
    assert np.allclose(np.linalg.norm(ours, axis=1), 1)


def test_the_edges_come_in_numpy_s_stable_order_of_their_weights():
    rng = np.random.default_rng(0)
    w = rng.random(50_000)
    w[::3], w[::7] = 1e-6, 0.5                          # ties, as planar patches give
    a, b = rng.integers(0, 2**32 - 1, (2, len(w)))       # node numbers to the packing's limit
    order = np.argsort(w, kind="stable")
    sa, sb = edges_by_weight(w, a, b)
    assert np.array_equal(sa, a[order]) and np.array_equal(sb, b[order])
    assert all(len(x) == 0 for x in edges_by_weight(w[:0], a[:0], b[:0]))
    with pytest.raises(ValueError, match="32 bits"):
        edges_by_weight(w[:2], np.array([0, 2**32]), b[:2])


def test_the_payloads_travel_with_their_keys():
    rng = np.random.default_rng(1)
    keys = rng.integers(0, 5, 20_000).astype(np.uint64) << np.uint64(40)    # ties; most passes move nothing
    keys[::11] = np.uint64(2**64 - 1)
    payloads = rng.integers(0, 2**63, len(keys)).astype(np.uint64) * np.uint64(2)
    expected = payloads[np.argsort(keys, kind="stable")]
    assert np.array_equal(sorted_payloads(keys.copy(), payloads), expected)          # payloads: the work space


@pytest.mark.parametrize("bits", [0, 16, 24, 48, 64])
def test_the_radix_order_is_numpy_s_stable_argsort_of_keys(bits):
    """Morton keys (the octree build's sort) of every width, batch bits included, with ties."""
    rng = np.random.default_rng(bits)
    keys = rng.integers(0, 2 ** min(bits, 62) + 1, 30_000, dtype=np.uint64) << np.uint64(max(bits - 62, 0))
    keys[::4] = keys[1]
    keys[5::9] |= np.uint64(1) << np.uint64(63)
    assert np.array_equal(radix_order(keys), np.argsort(keys, kind="stable"))
    assert len(radix_order(keys[:0])) == 0


def test_work_beside_the_orientation_sees_the_checked_points_once_and_changes_nothing():
    """``beside`` runs once on the points the normals are estimated for (strays dropped), the
    normals are the same bits as without it, and its error is raised; with normals given it runs
    too."""
    from model.octree.pointcloud import validate

    pts = scan(generate("chair", 9002), resolution=128)[0][::2].astype(np.float64)
    far = np.vstack([pts, pts.mean(0) + 1e3])                   # a stray: dropped before the work sees the points
    seen = []
    cloud = validate(far, None, beside=lambda p: seen.append(p.copy()))
    assert len(seen) == 1 and np.array_equal(seen[0], pts) and cloud.strays == 1
    assert np.array_equal(cloud.normals, validate(far, None).normals)
    assert np.array_equal(estimate_normals(pts, beside=lambda p: None), estimate_normals(pts))
    with pytest.raises(RuntimeError, match="beside failed"):
        estimate_normals(pts, beside=lambda p: (_ for _ in ()).throw(RuntimeError("beside failed")))
    seen.clear()
    validate(pts, cloud.normals, beside=seen.append)
    assert len(seen) == 1 and np.array_equal(seen[0], pts)


def test_the_distances_from_a_centre_are_numpy_s_norm_bit_for_bit():
    """:func:`distances_from` (the stray test's radii) sums the squares left to right (the order of
    ``np.linalg.norm(points - centre, axis=1)``, whose reduction NumPy may vectorise differently
    on another CPU, so it is not the reference here): the same bits on clouds of every scale."""
    from model.octree.pointcloud import distances_from

    rng = np.random.default_rng(3)
    for scale in (1e-9, 1.0, 3e7):
        pts = rng.normal(size=(50_000, 3)) * rng.random((50_000, 1)) * scale + rng.normal(size=3) * scale
        centre = np.median(pts, axis=0)
        d = pts - centre
        want = np.sqrt((d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1]) + d[:, 2] * d[:, 2])
        assert np.array_equal(distances_from(pts, centre), want)


def test_an_error_of_the_orientation_is_the_one_raised_when_the_work_beside_fails_too(monkeypatch):
    """The work beside is waited for, and its own error does not hide the orientation's."""
    import model.octree.pointcloud as pointcloud

    def broken(*args):
        raise ArithmeticError("orientation failed")

    done = []

    def failing(points):
        done.append(len(points))
        raise RuntimeError("beside failed")

    monkeypatch.setattr(pointcloud, "_oriented", broken)
    pts = np.random.default_rng(0).random((500, 3))
    with pytest.raises(ArithmeticError, match="orientation failed"):
        pointcloud.estimate_normals(pts, beside=failing)
    assert done == [500]
