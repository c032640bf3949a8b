"""Decoded octrees to patch-mesh files: GLB, glTF (buffers embedded), PLY (binary), OBJ."""

from __future__ import annotations

from dataclasses import dataclass

from model.octree import Octree
from model.octree.patches import patches_to_mesh

FORMATS = {"glb": "model/gltf-binary", "gltf": "model/gltf+json", "ply": "application/x-ply", "obj": "model/obj"}
"""Output format -> media type."""
ACCEPT = {v: k for k, v in FORMATS.items()} | {"text/plain": "obj", "application/octet-stream": "glb"}


@dataclass(frozen=True)
class MeshFile:
    """An encoded patch mesh and what the response headers report about it."""

    data: bytes
    media_type: str
    extension: str
    faces: int
    nodes: int
    leaves: dict[int, int]           # depth -> leaf patches


def choose_format(fmt: str | None, accept: str | None) -> str:
    """``format`` if given, else the first Accept media type we produce, else GLB."""
    if fmt:
        return fmt
    for part in (accept or "").split(","):
        kind = part.split(";")[0].strip().lower()
        if kind in ACCEPT:
            return ACCEPT[kind]
    return "glb"


def encode_mesh(octree: Octree, fmt: str, color_by_depth: bool = False) -> MeshFile:
    """One shape's leaf patches as a mesh file in the shape's own coordinates.

    Triangles are wound counter-clockwise about each patch's predicted normal (outward for a
    trained model), so renderers cull and shade them consistently.
    """
    import trimesh

    mesh = patches_to_mesh(octree, color_by_depth=color_by_depth)
    if fmt == "gltf":
        data = next(iter(trimesh.exchange.gltf.export_gltf(mesh, embed_buffers=True).values()))
    elif fmt == "ply":
        data = mesh.export(file_type="ply", encoding="binary")
    else:
        data = mesh.export(file_type=fmt)
    if isinstance(data, str):
        data = data.encode()
    leaves = {d: n for d, n in enumerate(octree.leaves_per_depth()) if n}
    return MeshFile(data, FORMATS[fmt], fmt, len(mesh.faces), sum(octree.nodes_per_depth()), leaves)
