"""Virtual scanner: dense oriented points from orthographic depth scans (O-CNN style).

Paper section 5 ("Dataset pre-processing") builds its octrees from points
and normals obtained by virtual 3D scanning.  Each of 14 views (6 face + 8
cube-corner directions) shoots a regular grid of parallel rays covering the
shape's bounding sphere; the first hit of each ray is a point and its normal is
the hit face's normal flipped towards the scanner.  Only visible surface is
kept (hidden faces of overlapping parts are dropped) and the inconsistent
face orientation of polygon soups is fixed.

Engines: ``"embree"`` (trimesh.ray with embreex, fast), ``"raster"`` (this
package's NumPy z-buffer rasterizer in orthographic mode: pixel centres are the
rays, so the first hit is exact and needs no extra dependency) and
``"trimesh"`` (trimesh's pure-Python ray_triangle intersector, which needs the
optional ``rtree`` package).  ``"auto"`` uses embree when available, else raster.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from .render import rasterize

DEFAULT_RESOLUTION = 160
"""Rays per side of each view's square grid (over the bounding sphere's diameter)."""


def scanner_directions() -> np.ndarray:
    """The 14 unit view directions (the direction rays travel): 6 axes and 8 cube corners."""
    axes = np.concatenate([np.eye(3), -np.eye(3)])
    corners = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=np.float64)
    return np.concatenate([axes, corners / np.sqrt(3.0)])


@dataclass
class Scan:
    """A scan: points and normals (float32, (N, 3)) plus, per point, the view index,
    its (u, v) coordinates in that view's plane, and the hit face index."""

    points: np.ndarray
    normals: np.ndarray
    view: np.ndarray
    uv: np.ndarray
    face: np.ndarray
    directions: np.ndarray
    radius: float


def embree_available() -> bool:
    """True when trimesh can use the embreex ray engine."""
    try:
        from trimesh.ray import ray_pyembree  # noqa: F401  deferred: embreex is optional (x86-64 only)
    except ImportError:
        return False
    return bool(getattr(trimesh.ray, "has_embree", True))


def _unit_face_normals(mesh: trimesh.Trimesh) -> np.ndarray:
    tri = np.asarray(mesh.vertices, dtype=np.float64)[np.asarray(mesh.faces)]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 1e-20)


def _view_basis(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    e1 = np.cross(helper, d)
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(d, e1)


def _hits_raster(mesh, centre, radius, d, e1, e2, res, offset):
    """First hits of the view's ray grid by orthographic z-buffering: (uv, t, face)."""
    rel = np.asarray(mesh.vertices, dtype=np.float64) - centre
    step = 2 * radius / res
    # Pixel (i, j) centre maps to u = -R + (j + 0.5) * step + offset[0], likewise v.
    px = (rel @ e1 + radius - offset[0]) / step
    py = (rel @ e2 + radius - offset[1]) / step
    depth = rel @ d
    zbuf, fid = rasterize(np.stack([px, py], axis=1), depth, mesh.faces, res, res)
    i, j = np.nonzero(fid >= 0)
    uv = np.stack([-radius + (j + 0.5) * step + offset[0], -radius + (i + 0.5) * step + offset[1]], axis=1)
    return uv, zbuf[i, j], fid[i, j]


def _hits_rays(intersector, centre, radius, d, e1, e2, res, offset):
    """First hits of the view's ray grid with a trimesh ray intersector: (uv, t, face)."""
    step = 2 * radius / res
    g = -radius + (np.arange(res) + 0.5) * step
    uu, vv = np.meshgrid(g + offset[0], g + offset[1])
    uv = np.stack([uu.ravel(), vv.ravel()], axis=1)
    origins = centre + uv[:, :1] * e1 + uv[:, 1:] * e2 - 1.5 * radius * d
    dirs = np.broadcast_to(d, origins.shape).copy()
    loc, ray_idx, tri_idx = intersector.intersects_location(origins, dirs, multiple_hits=False)
    t = (loc - centre) @ d
    return uv[ray_idx], t, tri_idx


def scan_detailed(
    mesh: trimesh.Trimesh,
    views: np.ndarray | None = None,
    resolution: int = DEFAULT_RESOLUTION,
    rng: np.random.Generator | None = None,
    min_cos: float = 0.05,
    engine: str = "auto",
) -> Scan:
    """Scan ``mesh`` from ``views`` (ray directions, default the 14 scanner directions).

    ``rng`` jitters each view's ray grid by a random sub-cell offset; hits whose
    |cos| between ray and face normal is below ``min_cos`` (grazing) are dropped.
    """
    if mesh is None or len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise ValueError("cannot scan an empty mesh (no faces)")
    verts = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(verts).all():
        raise ValueError("cannot scan a mesh with non-finite vertices")
    views = scanner_directions() if views is None else np.asarray(views, dtype=np.float64).reshape(-1, 3)
    views = views / np.linalg.norm(views, axis=1, keepdims=True)
    lo, hi = verts.min(axis=0), verts.max(axis=0)
    centre = (lo + hi) / 2
    radius = float(np.linalg.norm(verts - centre, axis=1).max()) * 1.001
    if radius <= 0:
        raise ValueError("cannot scan a mesh whose vertices all coincide")
    fn = _unit_face_normals(mesh)
    if engine == "auto":
        engine = "embree" if embree_available() else "raster"
    if engine == "embree":
        from trimesh.ray.ray_pyembree import RayMeshIntersector  # deferred: embreex is optional

        intersector = RayMeshIntersector(mesh)
    elif engine == "trimesh":
        from trimesh.ray.ray_triangle import RayMeshIntersector  # deferred: the engine asked for only

        intersector = RayMeshIntersector(mesh)
    elif engine != "raster":
        raise ValueError(f"unknown engine {engine!r}; use auto, embree, raster or trimesh")
    out = {k: [] for k in ("p", "n", "v", "uv", "f")}
    step = 2 * radius / resolution
    for vi, d in enumerate(views):
        e1, e2 = _view_basis(d)
        offset = np.zeros(2) if rng is None else rng.uniform(-0.5, 0.5, 2) * step
        if engine == "raster":
            uv, t, face = _hits_raster(mesh, centre, radius, d, e1, e2, resolution, offset)
        else:
            uv, t, face = _hits_rays(intersector, centre, radius, d, e1, e2, resolution, offset)
        n = fn[face]
        cos = n @ d
        keep = np.abs(cos) >= max(min_cos, 1e-6)
        n = np.where(cos[:, None] > 0, -n, n)[keep]
        uv, t, face = uv[keep], t[keep], face[keep]
        p = centre + uv[:, :1] * e1 + uv[:, 1:] * e2 + t[:, None] * d
        out["p"].append(p)
        out["n"].append(n)
        out["v"].append(np.full(len(p), vi, dtype=np.int64))
        out["uv"].append(uv)
        out["f"].append(face)
    return Scan(
        points=np.concatenate(out["p"]).astype(np.float32),
        normals=np.concatenate(out["n"]).astype(np.float32),
        view=np.concatenate(out["v"]),
        uv=np.concatenate(out["uv"]).astype(np.float32),
        face=np.concatenate(out["f"]).astype(np.int64),
        directions=views,
        radius=radius,
    )


def scan(
    mesh: trimesh.Trimesh,
    views: np.ndarray | None = None,
    resolution: int = DEFAULT_RESOLUTION,
    rng: np.random.Generator | None = None,
    min_cos: float = 0.05,
    engine: str = "auto",
) -> tuple[np.ndarray, np.ndarray]:
    """Virtual scan of ``mesh``: (points float32 (N, 3), outward normals float32 (N, 3)).

    See ``scan_detailed`` for the parameters; raises ValueError for empty meshes.
    """
    s = scan_detailed(mesh, views, resolution, rng, min_cos, engine)
    return s.points, s.normals
