"""Reading the octree's inputs: meshes (sampled densely) and point clouds, with or without normals."""

from __future__ import annotations

import os
import re
from dataclasses import dataclass

import numpy as np
import trimesh

from ..formats import MESH_FORMATS, POINT_FORMATS, identify, is_column_header, not_taken
from .errors import OctreeInputError
from .geometry import bounding_box
from .pointcloud import CUBE_FILL, Beside, PointCloud, validate

MESH_EXTENSIONS = (".obj", ".off", ".stl", ".glb", ".gltf", ".ply")
TEXT_POINT_EXTENSIONS = (".xyz", ".txt", ".pts", ".csv")
POINT_EXTENSIONS = TEXT_POINT_EXTENSIONS + (".npy", ".npz", ".ply")
SAMPLES_PER_VOXEL_EDGE = 3
"""Default mesh sampling: spacing of 1/3 finest voxel, so sampling gaps stay well below delta hat."""
MAX_DEFAULT_POINTS = 2_000_000
HEADER_BYTES = 4096
"""How much of a file its header checks read."""
MIN_DEFAULT_POINTS = 20_000


@dataclass(frozen=True)
class LoadedInput:
    """An input turned into oriented points, with how it was obtained."""

    cloud: PointCloud
    kind: str                       # "mesh" or "points"
    sample_spacing: float | None    # known spacing of mesh samples (input units), else None
    normals_estimated: bool


def load_input(path: str, depth: int, n_points: int | None = None, seed: int = 0,
               beside: Beside | None = None) -> LoadedInput:
    """Oriented points of any mesh trimesh reads, or of a point cloud file.

    Meshes are sampled uniformly by area with face normals; ``n_points`` defaults to a spacing
    of 1/3 finest voxel at ``depth``.  Point clouds without normals get estimated normals.
    ``beside``: work on the checked points, run beside their normals' orientation
    (:data:`~model.octree.pointcloud.Beside`).
    """
    if not os.path.isfile(path):
        raise OctreeInputError(f"{path}: no such file")
    if os.path.getsize(path) == 0:
        raise OctreeInputError(f"{path}: the file is empty")
    ext = os.path.splitext(path)[1].lower()
    if ext not in MESH_EXTENSIONS + POINT_EXTENSIONS:
        raise OctreeInputError(
            f"{path}: unknown format '{ext}'; use a mesh ({', '.join(MESH_EXTENSIONS)}) or a point "
            f"cloud ({', '.join(POINT_EXTENSIONS)})")
    if n_points is not None and n_points < 3:
        raise OctreeInputError(f"--points must be at least 3, got {n_points}")
    with open(path, "rb") as fh:
        kind = identify(fh.read(HEADER_BYTES))
    if kind.known and kind.loader is None:
        needed = f"a mesh ({MESH_FORMATS}) or a point cloud ({POINT_FORMATS}) is needed"
        raise OctreeInputError(f"{path}: {not_taken(kind, needed)}")
    if ext in TEXT_POINT_EXTENSIONS:
        return _points(_read_text(path), path, beside)
    if ext == ".npy":
        return _points(_read_npy(path), path, beside)
    if ext == ".npz":
        return _read_npz(path, beside)
    return _read_trimesh(path, depth, n_points, seed, beside)


def _points(arr: np.ndarray, path: str, beside: Beside | None) -> LoadedInput:
    if arr.ndim != 2 or arr.shape[1] not in (3, 6):
        raise OctreeInputError(
            f"{path}: expected N rows of 3 (x y z) or 6 (x y z nx ny nz) numbers, got shape {arr.shape}")
    normals = arr[:, 3:6] if arr.shape[1] == 6 else None
    return LoadedInput(validate(arr[:, :3], normals, beside=beside), "points", None, normals is None)


def _read_text(path: str) -> np.ndarray:
    try:
        with open(path, "r", encoding="utf-8-sig") as fh:
            lines = [ln for ln in fh if ln.strip() and not ln.lstrip().startswith(("#", "//"))]
    except UnicodeDecodeError:
        raise OctreeInputError(f"{path}: not a text point cloud (binary content)") from None
    if lines and is_column_header(lines[0]):                # "x y z" or "X,Y,Z,Nx,Ny,Nz"
        lines = lines[1:]
    rows = [ln.replace(",", " ").split() for ln in lines]
    if not rows:
        raise OctreeInputError(f"{path}: no points in the file")
    widths = {len(r) for r in rows}
    if len(widths) != 1:
        raise OctreeInputError(f"{path}: rows have different numbers of columns {sorted(widths)}")
    try:
        return np.asarray(rows, dtype=np.float64)
    except ValueError:
        raise OctreeInputError(f"{path}: found a value that is not a number") from None


def _read_npy(path: str) -> np.ndarray:
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError) as exc:
        raise OctreeInputError(f"{path}: not a readable .npy array ({exc})") from None
    return _real(arr, path, "the array")


def _real(arr: np.ndarray, path: str, what: str) -> np.ndarray:
    """``arr`` as float64 if it holds real numbers (integers or floats); complex, strings,
    booleans and objects are refused rather than cast."""
    if not (np.issubdtype(arr.dtype, np.integer) or np.issubdtype(arr.dtype, np.floating)):
        raise OctreeInputError(f"{path}: {what} holds {arr.dtype} values, not real numbers")
    return arr.astype(np.float64)


def _read_npz(path: str, beside: Beside | None) -> LoadedInput:
    try:
        data = np.load(path, allow_pickle=False)
        names = list(data.keys())
    except (ValueError, OSError) as exc:
        raise OctreeInputError(f"{path}: not a readable .npz archive ({exc})") from None
    pkey = next((k for k in ("points", "xyz", "pos", "positions") if k in names), None)
    if pkey is None:
        raise OctreeInputError(f"{path}: needs an array named 'points' (found {names})")
    nkey = next((k for k in ("normals", "normal", "nrm") if k in names), None)
    pts = _member(data, pkey, path)
    if nkey is None:
        return _points(pts, path, beside)
    nrm = _member(data, nkey, path)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise OctreeInputError(f"{path}: '{pkey}' must be (N, 3), got {pts.shape}")
    return LoadedInput(validate(pts, nrm, beside=beside), "points", None, False)


def _member(archive, name: str, path: str) -> np.ndarray:
    """One array of an NPZ archive as float64 (members are read, and refused, only when asked for:
    an object array is never unpickled)."""
    try:
        arr = np.asarray(archive[name])
    except (ValueError, OSError, EOFError) as exc:
        raise OctreeInputError(f"{path}: '{name}' is not a readable array ({exc})") from None
    return _real(arr, path, f"'{name}'")


def _read_trimesh(path: str, depth: int, n_points: int | None, seed: int, beside: Beside | None) -> LoadedInput:

    try:
        obj = trimesh.load(path, process=False)
    except Exception as exc:  # trimesh raises many types for corrupt files
        raise OctreeInputError(f"{path}: cannot be read as a mesh or point cloud ({type(exc).__name__}: {exc})") from None
    if isinstance(obj, trimesh.Scene):
        geoms = [g for g in obj.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
        if not geoms:
            geoms = [g for g in obj.dump() if isinstance(g, trimesh.PointCloud)]
            if not geoms:
                raise OctreeInputError(f"{path}: the file holds no triangles or points")
            obj = geoms[0]
        else:
            obj = trimesh.util.concatenate(geoms)
    with open(path, "rb") as fh:
        head = fh.read(HEADER_BYTES)
    declared = ply_vertex_count(head)
    if declared is not None and isinstance(obj, (trimesh.PointCloud, trimesh.Trimesh)) and len(obj.vertices) != declared:
        raise OctreeInputError(f"{path}: the PLY header declares {declared:,} vertices but the file holds "
                               f"{len(obj.vertices):,}; the file is truncated or corrupt")
    _check_text_counts(path, head)
    if isinstance(obj, trimesh.PointCloud) or (isinstance(obj, trimesh.Trimesh) and len(obj.faces) == 0):
        return _ply_points(obj, path, beside)
    if not isinstance(obj, trimesh.Trimesh):
        raise OctreeInputError(f"{path}: unsupported content ({type(obj).__name__})")
    return _sample_mesh(obj, path, depth, n_points, seed, beside)


def _check_text_counts(path: str, head: bytes) -> None:
    """ASCII PLY and OFF headers state how many vertex and face lines follow; a file holding fewer
    is truncated (the mesh reader would load the part it finds as if it were whole).  Binary PLY
    is checked by its reader's length test; other formats are not read again."""
    ascii_ply = head.startswith(b"ply") and b"format ascii" in head
    if not ascii_ply and b"OFF" not in head[:1024]:
        return
    with open(path, "rb") as fh:
        data = fh.read()
    lines = [ln.strip() for ln in data.splitlines()]
    if ascii_ply:
        if b"end_header" not in lines:
            return
        end = lines.index(b"end_header")
        counts = {m.group(1).decode(): int(m.group(2))
                  for m in (re.match(rb"element\s+(\S+)\s+(\d+)", ln) for ln in lines[:end]) if m}
        held = sum(1 for ln in lines[end + 1:] if ln)
        what, where = counts, "PLY"
    else:
        body = [ln for ln in lines if ln and not ln.startswith(b"#")]
        if not body or not body[0].startswith(b"OFF"):
            return
        fields = body[0][3:].split() or (body[1].split() if len(body) > 1 else [])
        if len(fields) < 2 or not all(f.isdigit() for f in fields[:2]):
            return
        what, where = {"vertex": int(fields[0]), "face": int(fields[1])}, "OFF"
        held = len(body) - (1 if body[0][3:].split() else 2)
    if held < sum(what.values()):
        declared = " and ".join(f"{n:,} {name}" for name, n in what.items())
        raise OctreeInputError(f"{path}: the {where} header declares {declared} lines but the file holds "
                               f"{held:,}; the file is truncated or corrupt")


def ply_vertex_count(head: bytes) -> int | None:
    """The vertex count a PLY file's first bytes declare (None for other files)."""
    if not head.startswith(b"ply"):
        return None
    m = re.search(rb"element\s+vertex\s+(\d+)", head)
    return int(m.group(1)) if m else None


def _ply_points(obj, path: str, beside: Beside | None) -> LoadedInput:
    pts = np.asarray(obj.vertices, dtype=np.float64)
    if len(pts) == 0:
        raise OctreeInputError(f"{path}: the file holds no points")
    normals = None
    raw = getattr(obj, "metadata", {}).get("_ply_raw", {}).get("vertex", {}).get("data")
    if raw is not None:
        # trimesh keeps PLY vertex properties as a structured array or a dict of columns.
        names = raw.dtype.names if hasattr(raw, "dtype") else tuple(raw.keys())
        if names and all(k in names for k in ("nx", "ny", "nz")):
            normals = np.stack([np.asarray(raw[k], dtype=np.float64).ravel() for k in ("nx", "ny", "nz")], axis=1)
            if len(normals) != len(pts):
                normals = None
    return LoadedInput(validate(pts, normals, beside=beside), "points", None, normals is None)


def _sample_mesh(mesh, path: str, depth: int, n_points: int | None, seed: int, beside: Beside | None) -> LoadedInput:

    v = np.asarray(mesh.vertices, dtype=np.float64)
    if not np.isfinite(v).all():
        raise OctreeInputError(f"{path}: the mesh has NaN or infinite vertex coordinates")
    area = mesh.area_faces
    good = np.isfinite(area) & (area > 0)
    if not good.any():
        raise OctreeInputError(f"{path}: every triangle has zero area; nothing to sample")
    total = float(area[good].sum())
    if n_points is None:
        lo, hi = bounding_box(v)
        extent = float((hi - lo).max())
        h = extent / CUBE_FILL / (1 << depth)
        spacing = h / SAMPLES_PER_VOXEL_EDGE
        n_points = int(np.clip(np.ceil(total / spacing ** 2), MIN_DEFAULT_POINTS, MAX_DEFAULT_POINTS))
    faces = np.flatnonzero(good)
    sub = trimesh.Trimesh(vertices=v, faces=np.asarray(mesh.faces)[faces], process=False)
    pts, fid = trimesh.sample.sample_surface(sub, n_points, seed=seed)
    normals = sub.face_normals[fid]
    return LoadedInput(validate(pts, normals, drop_strays=False, beside=beside), "mesh", float(np.sqrt(total / n_points)),
                       False)
