"""Shared inputs for the octree tests: analytic shapes and the test meshes (:mod:`tests.meshes`)."""

from __future__ import annotations

import numpy as np
import trimesh

from ..meshes import mesh_names, mesh_path  # noqa: F401  (the octree tests import it from here)

MESH_FILES = mesh_names()


def sphere_points(n: int, radius: float = 1.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Uniform samples of a sphere with exact outward normals."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return radius * d, d


def mesh_points(mesh: trimesh.Trimesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    pts, fid = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts, mesh.face_normals[fid]
