"""Rigid ICP alignment (Besl & McKay 1992) of a predicted point set to the ground truth.

The single-image comparison of paper section 5.3 reports the Chamfer distance after aligning each
prediction to its truth by ICP, as AtlasNet did for PointSetGen.  Point-to-point ICP with scipy's
k-d tree and the closed-form rigid fit (Kabsch/Umeyama, no scale, no reflection).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree


@dataclass(frozen=True)
class Alignment:
    """``aligned = source @ rotation.T + translation``; ``rms`` the final point-to-point RMS."""

    rotation: np.ndarray      # (3, 3), det +1
    translation: np.ndarray   # (3,)
    rms: float
    iterations: int

    def apply(self, points: np.ndarray) -> np.ndarray:
        return np.asarray(points, np.float64) @ self.rotation.T + self.translation


def rigid_fit(source: np.ndarray, target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares rotation and translation mapping paired ``source`` rows onto ``target``."""
    cs, ct = source.mean(0), target.mean(0)
    u, _, vt = np.linalg.svd((source - cs).T @ (target - ct))
    sign = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rot = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    return rot, ct - cs @ rot.T


def icp(source: np.ndarray, target: np.ndarray, iterations: int = 50, tolerance: float = 1e-7,
        trim: float = 1.0, max_points: int = 5000, seed: int = 0) -> Alignment:
    """Align ``source`` (N, 3) to ``target`` (M, 3) by point-to-point ICP from the identity.

    Each iteration pairs every source point with its nearest target point (the ``trim`` share of
    closest pairs is used, 1.0 = all) and solves the rigid fit; stops when the RMS changes by less
    than ``tolerance`` (relative) or after ``iterations``.  Returns the composed transform.  Sets
    larger than ``max_points`` are fitted on a fixed random subset of that size (the transform
    has 6 degrees of freedom; thousands of pairs pin it down), which keeps evaluation fast.
    """
    src = np.asarray(source, np.float64)
    tgt = np.asarray(target, np.float64)
    if len(src) < 3 or len(tgt) < 3:
        raise ValueError("ICP needs at least 3 points on each side")
    rng = np.random.default_rng(seed)
    if len(src) > max_points:
        src = src[rng.choice(len(src), max_points, replace=False)]
    if len(tgt) > 2 * max_points:
        tgt = tgt[rng.choice(len(tgt), 2 * max_points, replace=False)]
    if not 0 < trim <= 1:
        raise ValueError("trim must be in (0, 1]")
    tree = cKDTree(tgt)
    rot, trans = np.eye(3), np.zeros(3)
    prev = np.inf
    rms = np.inf
    it = 0
    for it in range(1, iterations + 1):
        moved = src @ rot.T + trans
        dist, idx = tree.query(moved)
        keep = np.argsort(dist)[:max(3, int(round(trim * len(dist))))] if trim < 1 else slice(None)
        rms = float(np.sqrt(np.mean(dist[keep] ** 2)))
        if np.isfinite(prev) and prev - rms <= tolerance * max(prev, 1e-12):
            break
        prev = rms
        r, t = rigid_fit(moved[keep], tgt[idx[keep]])
        rot, trans = r @ rot, r @ trans + t
    return Alignment(rot, trans, rms, it)
