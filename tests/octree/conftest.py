"""Shared inputs for the octree tests: analytic shapes and the real meshes in ../shared/meshes."""

from __future__ import annotations

import os

import numpy as np
import pytest
import trimesh

from ..shared import SHARED_MESHES as SHARED

SHARED_MESHES = str(SHARED)
MESH_FILES = sorted(f for f in os.listdir(SHARED_MESHES)
                    if f.endswith((".obj", ".off", ".stl", ".ply"))) if os.path.isdir(SHARED_MESHES) else []


def shared_mesh(name: str) -> str:
    path = os.path.join(SHARED_MESHES, name)
    if not os.path.isfile(path):
        pytest.skip(f"{path} is not available")
    return path


def sphere_points(n: int, radius: float = 1.0, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Uniform samples of a sphere with exact outward normals."""
    rng = np.random.default_rng(seed)
    d = rng.normal(size=(n, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    return radius * d, d


def mesh_points(mesh: trimesh.Trimesh, n: int, seed: int = 0) -> tuple[np.ndarray, np.ndarray]:
    pts, fid = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return pts, mesh.face_normals[fid]


@pytest.fixture(scope="session")
def bunny_points():
    mesh = trimesh.load(shared_mesh("stanford_bunny.obj"), force="mesh")
    return mesh_points(mesh, 150_000)
