"""Incomplete, noisy scans for the shape-completion task (paper section 5).

As in the paper: pick 3-5 random views of the virtual scanner, crop 1-3 random
regions from each view (a disc in that view's image plane around one of its
points) and perturb positions with small Gaussian noise.  The complete scan
is the target; the partial points (before noise) are a strict subset of it,
which ``partial_indices`` exposes for testing and pairing.
"""

from __future__ import annotations

import numpy as np
import trimesh

from .scanner import DEFAULT_RESOLUTION, Scan, scan_detailed


def partial_indices(
    scan: Scan,
    rng: np.random.Generator,
    n_views: tuple[int, int] = (3, 5),
    holes_per_view: tuple[int, int] = (1, 3),
    hole_radius: tuple[float, float] = (0.05, 0.15),
) -> tuple[np.ndarray, list[tuple[int, np.ndarray, float]]]:
    """Indices into ``scan`` kept by a random partial scan, and the holes cut.

    Ranges are inclusive; hole radii are fractions of the scan's bounding-sphere
    diameter.  Each hole is (view index, centre uv, radius).
    """
    present = np.unique(scan.view)
    k = int(rng.integers(n_views[0], n_views[1] + 1))
    k = min(k, len(present))
    chosen = rng.choice(present, size=k, replace=False)
    keep = []
    holes = []
    for v in np.sort(chosen):
        idx = np.nonzero(scan.view == v)[0]
        mask = np.ones(len(idx), dtype=bool)
        uv = scan.uv[idx].astype(np.float64)
        for _ in range(int(rng.integers(holes_per_view[0], holes_per_view[1] + 1))):
            centre = uv[rng.integers(len(uv))]
            r = float(rng.uniform(*hole_radius)) * 2 * scan.radius
            mask &= np.linalg.norm(uv - centre, axis=1) >= r
            holes.append((int(v), centre, r))
        keep.append(idx[mask])
    return np.concatenate(keep) if keep else np.zeros(0, dtype=np.int64), holes


def partial_from_scan(
    scan: Scan,
    rng: np.random.Generator,
    n_views: tuple[int, int] = (3, 5),
    holes_per_view: tuple[int, int] = (1, 3),
    hole_radius: tuple[float, float] = (0.05, 0.15),
    noise: float = 0.005,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Partial scan of a complete ``scan``: (points, normals, indices into the scan).

    ``noise`` is the Gaussian position sigma as a fraction of the bounding-sphere diameter.
    """
    idx, _ = partial_indices(scan, rng, n_views, holes_per_view, hole_radius)
    pts = scan.points[idx].astype(np.float64)
    pts += rng.normal(0.0, noise * 2 * scan.radius, pts.shape)
    return pts.astype(np.float32), scan.normals[idx].copy(), idx


def partial_scan(
    mesh: trimesh.Trimesh,
    rng: np.random.Generator,
    n_views: tuple[int, int] = (3, 5),
    holes_per_view: tuple[int, int] = (1, 3),
    hole_radius: tuple[float, float] = (0.05, 0.15),
    noise: float = 0.005,
    resolution: int = DEFAULT_RESOLUTION,
) -> tuple[np.ndarray, np.ndarray]:
    """Incomplete noisy scan of ``mesh`` from 3-5 of the 14 scanner views: (points, normals) float32."""
    full = scan_detailed(mesh, resolution=resolution)
    pts, nrm, _ = partial_from_scan(full, rng, n_views, holes_per_view, hole_radius, noise)
    return pts, nrm
