"""Evaluation helpers of paper section 5.2: dense samples of leaf patches, Chamfer, Hausdorff."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from .geometry import MAX_POLYGON, cube_polygons
from .octree import Octree
from .patches import PatchSet, leaf_patches


def sample_patches(octree: Octree, resolution: int = 128, seed: int | np.random.Generator = 0,
                   world: bool = True) -> np.ndarray:
    """One random point per sub-patch after subdividing every leaf patch to a ``resolution``^3 grid.

    This is the paper's protocol for turning a patch octree into a dense point cloud (at 128^3).
    Leaves finer than the grid give one point each.  Returns (P, 3) points, in the input's
    coordinates when ``world`` (single-shape octree) else in cube coordinates.
    """
    grid_depth = int(round(np.log2(resolution)))
    if resolution < 1 or 1 << grid_depth != resolution:
        raise ValueError(f"resolution must be a power of two, got {resolution}")
    rng = np.random.default_rng(seed)
    patches = leaf_patches(octree)
    out = []
    for depth in np.unique(patches.depth):
        sel = np.flatnonzero(patches.depth == depth)
        f = 1 << max(grid_depth - int(depth), 0)
        out.append(_sample_subdivided(patches, sel, f, rng))
    pts = np.concatenate(out) if out else np.zeros((0, 3))
    if world:
        if octree.batch_size != 1:
            raise ValueError("world coordinates need a single-shape octree; pass world=False")
        pts = octree.normalizations[0].to_world(pts)
    return pts


def _sample_subdivided(p: PatchSet, sel: np.ndarray, f: int, rng: np.random.Generator) -> np.ndarray:
    """Split the cubes of patches ``sel`` (same size) into f^3 sub-cubes; one point per sub-patch."""
    size = p.size[sel[0]] / f
    sub = (np.stack(np.meshgrid(*[np.arange(f)] * 3, indexing="ij"), -1).reshape(-1, 3) + 0.5) * size
    sub -= p.size[sel[0]] / 2.0                                        # sub-cube centres, local
    out = []
    chunk = max(1, 1_000_000 // len(sub))
    for s in range(0, len(sel), chunk):
        idx = sel[s:s + chunk]
        n, off = p.normal[idx], p.offset[idx]
        # Plane value at each sub-cube centre; it cuts the sub-cube iff |value| <= support.
        val = sub @ n.T + off[None]                                     # (S, M)
        support = 0.5 * size * np.abs(n).sum(1)
        si, mi = np.nonzero(np.abs(val) <= support[None])
        if len(si) == 0:
            continue
        verts, cnt = cube_polygons(n[mi], val[si, mi], size)
        ok = cnt >= 3
        pts = _random_in_polygons(verts[ok], cnt[ok], rng)
        out.append(pts + sub[si[ok]] + p.center[idx[mi[ok]]])
    return np.concatenate(out) if out else np.zeros((0, 3))


def _random_in_polygons(verts: np.ndarray, count: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """One uniformly random point in each convex polygon (fan triangles chosen by area)."""
    a = verts[:, :1]
    b, c = verts[:, 1:-1], verts[:, 2:]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=2)        # (M, 4)
    area[np.arange(1, MAX_POLYGON - 1)[None] + 1 >= count[:, None]] = 0.0
    cum = np.cumsum(area, axis=1)
    total = cum[:, -1:]
    r = rng.random((len(verts), 1)) * total
    tri = np.minimum((cum < r).sum(1), MAX_POLYGON - 3)
    rows = np.arange(len(verts))
    u, v = rng.random(len(verts)), rng.random(len(verts))
    flip = u + v > 1
    u[flip], v[flip] = 1 - u[flip], 1 - v[flip]
    a = verts[:, 0]
    return a + u[:, None] * (b[rows, tri] - a) + v[:, None] * (c[rows, tri] - a)


@dataclass(frozen=True)
class Nearest:
    """The nearest distances both ways between a reference set R and a point set P:
    ``to_points[i]`` from R's i-th point to P (its nearest: P[``to_index[i]``]), ``from_points[j]``
    from P's j-th point to R (its nearest: R[``from_index[j]``])."""

    to_points: np.ndarray
    from_points: np.ndarray
    to_index: np.ndarray
    from_index: np.ndarray

    def chamfer(self) -> float:
        """:func:`chamfer_distance` (R, P)."""
        return float((self.to_points ** 2).mean()) + float((self.from_points ** 2).mean())

    def fscore(self, threshold: float) -> float:
        """The harmonic mean of precision (share of P within ``threshold`` of R) and recall
        (share of R within ``threshold`` of P)."""
        precision = float((self.from_points <= threshold).mean())
        recall = float((self.to_points <= threshold).mean())
        return 2 * precision * recall / (precision + recall) if precision + recall else 0.0


class Reference:
    """A point set measured against many others (a shape's truth): its k-d tree is built once."""

    def __init__(self, points: np.ndarray):
        self.points = _nonempty(points)
        self._tree = cKDTree(self.points)

    def nearest(self, points: np.ndarray) -> Nearest:
        """The nearest distances both ways between this set and ``points`` (non-empty)."""
        p = _nonempty(points)
        (to, to_index), (back, back_index) = cKDTree(p).query(self.points, workers=-1), self._tree.query(p, workers=-1)
        return Nearest(to, back, to_index, back_index)

    def chamfer(self, points: np.ndarray) -> float:
        """:func:`chamfer_distance` (this set, ``points``)."""
        return self.nearest(points).chamfer()


def chamfer_distance(ground_truth: np.ndarray, predicted: np.ndarray) -> float:
    """The paper's Chamfer distance: mean squared nearest distance, both directions, summed."""
    return Reference(ground_truth).chamfer(predicted)


def mean_squared_distance(a: np.ndarray, b: np.ndarray) -> float:
    """One direction of the Chamfer distance: the mean squared distance from each point of ``a``
    to its nearest point of ``b``."""
    d, _ = cKDTree(_nonempty(b)).query(_nonempty(a), workers=-1)
    return float((d ** 2).mean())


def missing_distance(ground_truth: np.ndarray, observed: np.ndarray, predicted: np.ndarray,
                     gap: float) -> float | None:
    """Shape completion's own measure: the mean squared distance from the truth points farther
    than ``gap`` from every ``observed`` point (the missing part) to ``predicted``; None when
    nothing is missing.  A do-nothing prediction (the observed points) scores at least gap^2."""
    part = missing_part(ground_truth, observed, gap)
    return mean_squared_distance(part, predicted) if len(part) else None


def missing_part(ground_truth: np.ndarray, observed: np.ndarray, gap: float) -> np.ndarray:
    """The truth points farther than ``gap`` from every ``observed`` point (possibly none)."""
    g = _nonempty(ground_truth)
    return g[cKDTree(_nonempty(observed)).query(g, workers=-1)[0] > gap]


def hausdorff_distance(a: np.ndarray, b: np.ndarray) -> float:
    """Symmetric Hausdorff distance between two point sets."""
    a, b = _nonempty(a), _nonempty(b)
    return float(max(cKDTree(b).query(a, workers=-1)[0].max(), cKDTree(a).query(b, workers=-1)[0].max()))


def _nonempty(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 2 or x.shape[1] != 3 or len(x) == 0:
        raise ValueError(f"expected a non-empty (N, 3) point array, got shape {x.shape}")
    return x
