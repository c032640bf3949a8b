"""Real mesh files for the tests, generated here so that every test runs on a fresh clone.

Each stands in for a kind of real input the pipeline must cope with, written in the file format
such inputs come in: a ModelNet-style polygon soup of overlapping boxes (OFF), a CAD part with
sharp edges and through-holes (binary STL, made with manifold3d's booleans), a sculpted organic
shape (OBJ), a knotted tube of genus 1 (binary PLY) and an airplane soup with parts thinner than
a finest voxel (ASCII STL).  They are deterministic, made by this file (no licence to record),
and written once per test process.  When the research meshes in ``../shared/meshes`` (or
``AOCNN_SHARED_MESHES``) are present, :func:`mesh_names` adds them; they are never required.
"""

from __future__ import annotations

import atexit
import functools
import os
import shutil
import tempfile
from pathlib import Path

import numpy as np
import trimesh

from .shared import SHARED_MESHES

MESH_SUFFIXES = (".obj", ".off", ".stl", ".ply")


def chair_soup() -> trimesh.Trimesh:
    """A chair of 8 overlapping boxes, concatenated without merging (8 components, not
    watertight as a whole: ModelNet's mn40_chair_0002 is built the same way)."""
    boxes = [((0.50, 0.05, 0.50), (0.0, 0.45, 0.0)),                        # seat
             ((0.50, 0.55, 0.05), (0.0, 0.75, -0.225))]                     # back
    boxes += [((0.05, 0.45, 0.05), (x, 0.225, z)) for x in (-0.2, 0.2) for z in (-0.2, 0.2)]  # legs
    boxes += [((0.45, 0.04, 0.04), (0.0, 0.12, z)) for z in (-0.2, 0.2)]   # rails
    parts = [trimesh.creation.box(extents=e, transform=trimesh.transformations.translation_matrix(c))
             for e, c in boxes]
    return trimesh.util.concatenate(parts)


def cad_block() -> trimesh.Trimesh:
    """A machined block: two through-holes, a slot and a boss (sharp edges, flat faces, genus 2)."""
    import manifold3d as m3

    block = m3.Manifold.cube((1.0, 0.6, 0.3), center=True)
    hole = m3.Manifold.cylinder(0.5, 0.09, 0.09, 48, center=True)
    for x in (-0.3, 0.3):
        block = block - hole.translate((x, 0.0, 0.0))
    block = block - m3.Manifold.cube((0.3, 0.7, 0.12), center=True).translate((0.0, 0.0, 0.12))
    block = block + m3.Manifold.cylinder(0.2, 0.12, 0.12, 48, center=True).translate((0.0, 0.0, -0.2))
    mesh = block.to_mesh()
    return trimesh.Trimesh(np.asarray(mesh.vert_properties)[:, :3], np.asarray(mesh.tri_verts), process=True)


def blob() -> trimesh.Trimesh:
    """A sculpted closed surface: a sphere displaced by low-frequency waves (bulges and dents)."""
    mesh = trimesh.creation.icosphere(subdivisions=4)
    v = mesh.vertices
    x, y, z = v.T
    r = 1.0 + 0.22 * np.sin(3 * x + 1) * np.cos(2 * y) + 0.15 * np.sin(4 * z + 2 * x) + 0.1 * np.cos(5 * y * z)
    return trimesh.Trimesh(v * r[:, None] * (1.0, 0.8, 0.9), mesh.faces, process=False)


def knot(p: int = 2, q: int = 3, rings: int = 240, sides: int = 16, radius: float = 0.28) -> trimesh.Trimesh:
    """A (p, q) torus knot swept by a circle: one closed tube, genus 1."""
    t = np.linspace(0, 2 * np.pi, rings, endpoint=False)
    def curve(s):
        return np.stack([(2 + np.cos(q * s)) * np.cos(p * s), (2 + np.cos(q * s)) * np.sin(p * s),
                         -np.sin(q * s)], 1)
    c = curve(t)
    tangent = curve(t + 1e-4) - curve(t - 1e-4)
    tangent /= np.linalg.norm(tangent, axis=1, keepdims=True)
    normal = np.cross(tangent, np.array([0.0, 0.0, 1.0]))
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)
    binormal = np.cross(tangent, normal)
    a = np.linspace(0, 2 * np.pi, sides, endpoint=False)
    verts = (c[:, None] + radius * (np.cos(a)[None, :, None] * normal[:, None]
                                    + np.sin(a)[None, :, None] * binormal[:, None])).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(rings), np.arange(sides), indexing="ij")
    a0, a1 = i * sides + j, i * sides + (j + 1) % sides
    b0, b1 = ((i + 1) % rings) * sides + j, ((i + 1) % rings) * sides + (j + 1) % sides
    faces = np.concatenate([np.stack([a0, b0, b1], -1).reshape(-1, 3), np.stack([a0, b1, a1], -1).reshape(-1, 3)])
    mesh = trimesh.Trimesh(verts, faces, process=False)
    if mesh.volume < 0:
        mesh.invert()
    return mesh


def airplane_soup() -> trimesh.Trimesh:
    """An airplane as overlapping parts (fuselage, wings, tailplane, fin): a polygon soup whose
    wings are 0.012 thick, under one finest voxel at depth 6 (0.016 of the cube)."""
    def box(extents, centre):
        return trimesh.creation.box(extents=extents, transform=trimesh.transformations.translation_matrix(centre))
    fuselage = trimesh.creation.cylinder(radius=0.06, height=1.0, sections=24,
                                         transform=trimesh.transformations.rotation_matrix(np.pi / 2, (0, 1, 0)))
    parts = [fuselage, box((0.22, 0.012, 0.9), (0.05, 0.0, 0.0)), box((0.1, 0.01, 0.34), (-0.44, 0.02, 0.0)),
             box((0.12, 0.16, 0.01), (-0.44, 0.1, 0.0))]
    return trimesh.util.concatenate(parts)


GENERATED = {"chair_soup.off": chair_soup, "cad_block.stl": cad_block, "blob.obj": blob, "knot.ply": knot,
             "airplane_soup.stl": airplane_soup}
"""File name -> the function that makes it; the suffix is the format it is written in."""


@functools.lru_cache(maxsize=None)
def _folder() -> Path:
    """The generated meshes' folder, made once per test process and removed when it ends."""
    path = tempfile.mkdtemp(prefix="aocnn-test-meshes-")
    atexit.register(shutil.rmtree, path, True)
    return Path(path)


def mesh_path(name: str) -> str:
    """The path of a test mesh: a generated one (written on first use), else a shared one.
    Raises FileNotFoundError naming the shared folder when ``name`` is neither."""
    if name in GENERATED:
        path = _folder() / name
        if not path.is_file():
            mesh = GENERATED[name]()
            if name.endswith(".stl") and name.startswith("airplane"):
                data = trimesh.exchange.stl.export_stl_ascii(mesh).encode()
            else:
                data = mesh.export(file_type=path.suffix[1:])
            tmp = path.with_suffix(".tmp")
            tmp.write_bytes(data.encode() if isinstance(data, str) else data)
            os.replace(tmp, path)
        return str(path)
    path = SHARED_MESHES / name
    if not path.is_file():
        raise FileNotFoundError(f"{name} is neither a generated test mesh nor in {SHARED_MESHES}")
    return str(path)


def mesh_names() -> list[str]:
    """Every generated test mesh, then the shared research meshes where that folder exists."""
    shared = sorted(p.name for p in SHARED_MESHES.iterdir() if p.suffix in MESH_SUFFIXES) \
        if SHARED_MESHES.is_dir() else []
    return list(GENERATED) + shared
