"""Decoded octrees to mesh files: GLB, glTF (buffer embedded), PLY (binary), OBJ.

Written directly from the mesh's arrays (:func:`model.surface.surface_mesh`: the closed surface,
or the paper's leaf patches): the formats are simple and NumPy writes them in a few
milliseconds, where a general scene exporter spent most of a request.  Triangles are wound
counter-clockwise seen from outside (patches: about each patch's predicted normal).  A closed
mesh is single-sided in glTF, patches double-sided.  GLB and glTF pass the Khronos validator
(tests).
"""

from __future__ import annotations

import base64
import json
import struct
from dataclasses import dataclass

import numpy as np

from model.octree import Octree
from model.octree.geometry import bounding_box
from model.octree.patches import depth_colors
from model.surface import DEFAULT_SURFACE, SurfaceMesh, surface_mesh

FORMATS = {"glb": "model/gltf-binary", "gltf": "model/gltf+json", "ply": "application/x-ply", "obj": "model/obj"}
"""Output format -> media type."""
ACCEPT = {v: k for k, v in FORMATS.items()} | {"text/plain": "obj", "application/octet-stream": "glb"}
GENERATOR = "adaptive-ocnn"


@dataclass(frozen=True)
class MeshFile:
    """An encoded mesh and what the response headers report about it."""

    data: bytes
    media_type: str
    extension: str
    faces: int
    nodes: int
    leaves: dict[int, int]           # depth -> leaf patches
    surface: str                     # watertight or patches
    closed: bool


def choose_format(fmt: str | None, accept: str | None) -> str:
    """``format`` if given, else the Accept media type we produce with the highest q (ties: the
    first listed; ``*/*`` and ``model/*`` mean GLB), else GLB."""
    if fmt:
        return fmt
    offers = []
    for i, part in enumerate((accept or "").split(",")):
        kind, *params = [p.strip().lower() for p in part.split(";")]
        q = 1.0
        for p in params:
            if p.startswith("q="):
                try:
                    q = float(p[2:])
                except ValueError:
                    q = 0.0
        found = ACCEPT.get(kind) or ("glb" if kind in ("*/*", "model/*") else None)
        if found and q > 0:
            offers.append((-q, i, found))
    return min(offers)[2] if offers else "glb"


def _pad4(b: bytes, fill: bytes = b"\x00") -> bytes:
    return b + fill * (-len(b) % 4)


def _gltf(m: SurfaceMesh, colors: np.ndarray | None) -> tuple[dict, bytes]:
    """The glTF 2.0 document (one mesh, one triangle primitive) and its binary buffer."""
    pos = np.ascontiguousarray(m.vertices, dtype=np.float32)
    idx = np.ascontiguousarray(m.faces, dtype=np.uint32).ravel()
    parts = [(pos.tobytes(), 34962), (idx.tobytes(), 34963)]
    if colors is not None:
        parts.insert(1, (np.ascontiguousarray(colors, dtype=np.uint8).tobytes(), 34962))
    views, blob = [], b""
    for data, target in parts:
        views.append({"buffer": 0, "byteOffset": len(blob), "byteLength": len(data), "target": target})
        blob += _pad4(data)
    lo, hi = bounding_box(pos)
    accessors = [{"bufferView": 0, "componentType": 5126, "count": len(pos), "type": "VEC3",
                  "min": lo.tolist(), "max": hi.tolist()}]
    attributes = {"POSITION": 0}
    if colors is not None:
        accessors.append({"bufferView": 1, "componentType": 5121, "normalized": True, "count": len(pos), "type": "VEC4"})
        attributes["COLOR_0"] = 1
    accessors.append({"bufferView": len(views) - 1, "componentType": 5125, "count": len(idx), "type": "SCALAR"})
    doc = {"asset": {"version": "2.0", "generator": GENERATOR}, "scene": 0, "scenes": [{"nodes": [0]}],
           "nodes": [{"mesh": 0, "name": m.kind}],
           "meshes": [{"name": m.kind, "primitives": [{"attributes": attributes, "indices": len(accessors) - 1,
                                                        "mode": 4, "material": 0}]}],
           "materials": [{"name": m.kind, "doubleSided": not m.closed,
                          "pbrMetallicRoughness": {"baseColorFactor": [0.8, 0.8, 0.82, 1.0], "metallicFactor": 0.0,
                                                   "roughnessFactor": 0.8}}],
           "accessors": accessors, "bufferViews": views, "buffers": [{"byteLength": len(blob)}]}
    return doc, blob


def glb_bytes(m: SurfaceMesh, colors: np.ndarray | None = None) -> bytes:
    doc, blob = _gltf(m, colors)
    js = _pad4(json.dumps(doc, separators=(",", ":")).encode(), b" ")
    total = 12 + 8 + len(js) + 8 + len(blob)
    return (struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(js), b"JSON") + js
            + struct.pack("<I4s", len(blob), b"BIN\x00") + blob)


def gltf_bytes(m: SurfaceMesh, colors: np.ndarray | None = None) -> bytes:
    doc, blob = _gltf(m, colors)
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(blob).decode()
    return json.dumps(doc, separators=(",", ":")).encode()


def ply_bytes(m: SurfaceMesh, colors: np.ndarray | None = None) -> bytes:
    """Binary little-endian PLY: float vertices (with RGBA when coloured), uchar-count int faces."""
    props = "property float x\nproperty float y\nproperty float z\n"
    vtype = [("p", "<f4", 3)]
    if colors is not None:
        props += "property uchar red\nproperty uchar green\nproperty uchar blue\nproperty uchar alpha\n"
        vtype.append(("c", "u1", 4))
    head = (f"ply\nformat binary_little_endian 1.0\ncomment {GENERATOR} {m.kind} mesh\nelement vertex {len(m.vertices)}\n"
            f"{props}element face {len(m.faces)}\nproperty list uchar int vertex_indices\nend_header\n").encode()
    v = np.empty(len(m.vertices), vtype)
    v["p"] = m.vertices
    if colors is not None:
        v["c"] = colors
    f = np.empty(len(m.faces), [("n", "u1"), ("i", "<i4", 3)])
    f["n"], f["i"] = 3, m.faces
    return head + v.tobytes() + f.tobytes()


def obj_bytes(m: SurfaceMesh, colors: np.ndarray | None = None) -> bytes:
    """Wavefront OBJ (vertex colours, where asked, as the common ``v x y z r g b`` extension)."""
    # one %-format over all rows: 3x (vertices) and 10x (faces) faster than a format per row
    if colors is not None:
        rows, line = np.hstack([m.vertices, colors[:, :3] / 255.0]), "v %.6f %.6f %.6f %.4f %.4f %.4f\n"
    else:
        rows, line = m.vertices, "v %.6f %.6f %.6f\n"
    v = (line * len(rows)) % tuple(rows.ravel().tolist())
    f = ("f %d %d %d\n" * len(m.faces)) % tuple((m.faces + 1).ravel().tolist())
    return f"# {GENERATOR} {m.kind} mesh\n{v}{f}".encode()


WRITERS = {"glb": glb_bytes, "gltf": gltf_bytes, "ply": ply_bytes, "obj": obj_bytes}


def encode_mesh(octree: Octree, fmt: str, color_by_depth: bool = False, surface: str = DEFAULT_SURFACE) -> MeshFile:
    """One shape's ``surface`` (:data:`model.surface.SURFACES`) as a mesh file in the shape's own
    coordinates."""
    return encode(surface_mesh(octree, surface), octree, fmt, color_by_depth)


def encode(m: SurfaceMesh, octree: Octree, fmt: str, color_by_depth: bool = False) -> MeshFile:
    """The mesh ``m`` of ``octree`` as a file of format ``fmt`` (vertex colours by octree depth
    where asked)."""
    colors = depth_colors(m.vertex_depth) if color_by_depth else None
    leaves = {d: n for d, n in enumerate(octree.leaves_per_depth()) if n}
    return MeshFile(WRITERS[fmt](m, colors), FORMATS[fmt], fmt, len(m.faces), sum(octree.nodes_per_depth()), leaves,
                    m.kind, m.closed)
