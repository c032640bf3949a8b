"""Discovery and loading of real dataset layouts: ModelNet40, ShapeNetCore.v2, 3D-R2N2, and a
plain folder of mesh files.

Walk a dataset root and yield dataclass records (category, shape id, split,
paths) so that the dataset builder can treat real data like generated data.
``load_mesh`` returns a single Trimesh from any mesh file, with a tolerant OFF
reader for ModelNet's fused headers ("OFF490 518 0").
"""

from __future__ import annotations

import csv
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Iterator

import numpy as np
import trimesh

from ..octree.geometry import to_y_up
from .shapes import SYNSETS, split_from_key

SYNSET_TO_CATEGORY: dict[str, str] = {v: k for k, v in SYNSETS.items()}


@dataclass
class MeshRecord:
    """One shape of a mesh dataset."""

    category: str
    shape_id: str
    split: str
    mesh_path: Path


@dataclass
class ViewMetadata:
    """One rendering_metadata.txt row of 3D-R2N2."""

    azimuth: float
    elevation: float
    in_plane_rotation: float
    distance_ratio: float
    fov: float


@dataclass
class RenderRecord:
    """One shape of the 3D-R2N2 renderings: image paths with their camera rows."""

    category: str
    shape_id: str
    split: str
    image_paths: list[Path]
    metadata: list[ViewMetadata]
    mesh_path: Path | None = None
    synset: str = field(default="")


def _check_root(root: Path, what: str) -> Path:
    root = Path(root)
    if not root.is_dir():
        raise ValueError(f"{what} root {root} is not a directory")
    return root


def iter_modelnet40(root: str | Path) -> Iterator[MeshRecord]:
    """Yield ModelNet40 shapes from ``<root>/<class>/{train,test}/*.off`` (sorted)."""
    root = _check_root(Path(root), "ModelNet40")
    found = False
    for cls in sorted(p for p in root.iterdir() if p.is_dir()):
        for split in ("train", "test"):
            d = cls / split
            if not d.is_dir():
                continue
            for f in sorted(d.glob("*.off")):
                found = True
                yield MeshRecord(cls.name, f.stem, split, f)
    if not found:
        raise ValueError(f"{root} does not look like ModelNet40: no <class>/train|test/*.off files")


def y_up(mesh: trimesh.Trimesh, up: str) -> trimesh.Trimesh:
    """``mesh``, whose up axis is ``up``, rotated so that it is y-up, the convention of the
    generators, the renders and ShapeNet (ModelNet40's meshes are z-up; :func:`to_y_up`): a
    rotation, so the shape is unchanged; the mesh itself when it already is."""
    rotation = to_y_up(up)
    if up == "y":
        return mesh
    return trimesh.Trimesh(vertices=np.asarray(mesh.vertices) @ rotation.T, faces=mesh.faces, process=False)


MESH_SUFFIXES = (".obj", ".off", ".stl", ".ply", ".glb", ".gltf")
"""The mesh files a plain folder (:func:`iter_mesh_folder`) is read for."""


def folder_category(stem: str) -> str:
    """The category of a mesh in a plain folder: the one of :data:`SYNSETS`'s categories its file
    name names as a word ("mn40_chair_0001" -> "chair"), else "unknown"."""
    words = {w for w in re.split(r"[^a-z]+", stem.lower()) if w}
    named = sorted(words & set(SYNSETS))
    return named[0] if len(named) == 1 else "unknown"


def iter_mesh_folder(root: str | Path) -> Iterator[MeshRecord]:
    """Yield every mesh file directly in ``root`` (:data:`MESH_SUFFIXES`, sorted) as a shape of
    the test split: a folder of one's own meshes to evaluate the models on.  Its shape id is the
    file's stem, its category :func:`folder_category`; ValueError when two files share a stem or
    the folder holds no mesh."""
    root = _check_root(Path(root), "mesh folder")
    files = sorted(p for p in root.iterdir() if p.is_file() and p.suffix.lower() in MESH_SUFFIXES)
    if not files:
        raise ValueError(f"{root} holds no mesh files ({', '.join(MESH_SUFFIXES)})")
    seen: dict[str, Path] = {}
    for f in files:
        if f.stem in seen:
            raise ValueError(f"{seen[f.stem].name} and {f.name} in {root} share the shape id {f.stem!r}; rename one")
        seen[f.stem] = f
        yield MeshRecord(folder_category(f.stem), f.stem, "test", f)


def read_split_csv(path: str | Path) -> dict[str, str]:
    """Map modelId -> split from a ShapeNet split CSV (id,synsetId,subSynsetId,modelId,split)."""
    with open(path, newline="") as fh:
        reader = csv.DictReader(fh)
        if reader.fieldnames is None or not {"modelId", "split"} <= set(reader.fieldnames):
            raise ValueError(f"{path}: split CSV needs columns modelId and split, got {reader.fieldnames}")
        return {row["modelId"].strip(): row["split"].strip() for row in reader}


def _split_of(splits: dict[str, str] | None, synset: str, model: str) -> str | None:
    """The model's split from a split CSV (None when the CSV leaves it out), else a stable hash."""
    if splits is None:
        return split_from_key(synset, model)
    return _normalise_split(splits[model]) if model in splits else None


def _normalise_split(s: str) -> str:
    return {"validation": "val", "valid": "val"}.get(s, s)


def iter_shapenet(
    root: str | Path, split_csv: str | Path | None = None, categories: tuple[str, ...] | None = None
) -> Iterator[MeshRecord]:
    """Yield ShapeNetCore.v2 shapes from ``<root>/<synset>/<model>/models/model_normalized.obj``.

    Only the 13 synsets of SYNSETS (or ``categories``) are read; split from the
    CSV when given (models missing from it are skipped), else an 80/10/10 hash.
    """
    root = _check_root(Path(root), "ShapeNetCore.v2")
    splits = read_split_csv(split_csv) if split_csv is not None else None
    wanted = set(categories) if categories is not None else set(SYNSETS)
    synset_dirs = [p for p in sorted(root.iterdir()) if p.is_dir() and p.name.isdigit() and len(p.name) == 8]
    if not synset_dirs:
        raise ValueError(f"{root} does not look like ShapeNetCore.v2: no 8-digit synset directories")
    for sd in synset_dirs:
        cat = SYNSET_TO_CATEGORY.get(sd.name)
        if cat is None or cat not in wanted:
            continue
        for md in sorted(p for p in sd.iterdir() if p.is_dir()):
            mesh = md / "models" / "model_normalized.obj"
            if not mesh.is_file():
                continue
            split = _split_of(splits, sd.name, md.name)
            if split is None:
                continue
            yield MeshRecord(cat, md.name, split, mesh)


def read_r2n2_metadata(path: str | Path) -> list[ViewMetadata]:
    """Parse rendering_metadata.txt: one view per line, 5 floats."""
    rows = []
    for n, line in enumerate(Path(path).read_text().splitlines(), 1):
        if not line.strip():
            continue
        vals = line.replace(",", " ").split()
        if len(vals) != 5:
            raise ValueError(f"{path}:{n}: expected 5 numbers, got {len(vals)}")
        try:
            rows.append(ViewMetadata(*(float(v) for v in vals)))
        except ValueError as e:
            raise ValueError(f"{path}:{n}: {e}") from None
    return rows


def iter_r2n2(
    root: str | Path, shapenet_root: str | Path | None = None, split_csv: str | Path | None = None
) -> Iterator[RenderRecord]:
    """Yield 3D-R2N2 renderings from ``<root>/<synset>/<model>/rendering/``.

    Image order follows renderings.txt (3D-R2N2's name; rendering.txt is accepted too), paired
    line by line with rendering_metadata.txt; ``shapenet_root`` fills in the mesh path if present.
    """
    root = _check_root(Path(root), "3D-R2N2 renderings")
    splits = read_split_csv(split_csv) if split_csv is not None else None
    found = False
    for sd in sorted(p for p in root.iterdir() if p.is_dir()):
        cat = SYNSET_TO_CATEGORY.get(sd.name)
        if cat is None:
            continue
        for md in sorted(p for p in sd.iterdir() if p.is_dir()):
            rd = md / "rendering"
            listing = next((rd / n for n in ("renderings.txt", "rendering.txt") if (rd / n).is_file()), None)
            meta_file = rd / "rendering_metadata.txt"
            if listing is None or not meta_file.is_file():
                continue
            found = True
            names = [s.strip() for s in listing.read_text().splitlines() if s.strip()]
            meta = read_r2n2_metadata(meta_file)
            if len(names) != len(meta):
                raise ValueError(f"{rd}: {listing.name} lists {len(names)} images but metadata has {len(meta)} rows")
            images = [rd / n for n in names]
            missing = [p for p in images if not p.is_file()]
            if missing:
                raise ValueError(f"{rd}: missing image {missing[0].name}")
            split = _split_of(splits, sd.name, md.name)
            if split is None:
                continue
            mesh = None
            if shapenet_root is not None:
                cand = Path(shapenet_root) / sd.name / md.name / "models" / "model_normalized.obj"
                mesh = cand if cand.is_file() else None
            yield RenderRecord(cat, md.name, split, images, meta, mesh, sd.name)
    if not found:
        raise ValueError(f"{root} does not look like 3D-R2N2 renderings: no <synset>/<model>/rendering/renderings.txt")


def read_off(path: str | Path) -> trimesh.Trimesh:
    """Read an OFF file tolerantly: fused "OFF<nv> <nf> <ne>" headers, comments,
    COFF/NOFF variants, polygon faces (fan-triangulated) and trailing colours."""
    text = Path(path).read_text(errors="replace")
    lines = [ln.split("#", 1)[0].strip() for ln in text.splitlines()]
    lines = [ln for ln in lines if ln]
    if not lines or "OFF" not in lines[0].upper().split()[0]:
        raise ValueError(f"{path}: not an OFF file (first line {lines[0][:40]!r})" if lines else f"{path}: empty file")
    head = lines[0].split()
    first = head[0]
    rest = first[first.upper().index("OFF") + 3:]
    counts = ([rest] if rest else []) + head[1:]
    i = 1
    while len(counts) < 3 and i < len(lines):
        counts += lines[i].split()
        i += 1
    try:
        nv, nf = int(counts[0]), int(counts[1])
    except (ValueError, IndexError):
        raise ValueError(f"{path}: cannot parse OFF counts from {lines[: i + 1]}") from None
    if len(lines) < i + nv + nf:
        raise ValueError(f"{path}: header promises {nv} vertices and {nf} faces but the file is shorter")
    verts = np.array([ln.split()[:3] for ln in lines[i:i + nv]], dtype=np.float64).reshape(-1, 3)
    tris = []
    for ln in lines[i + nv:i + nv + nf]:
        vals = ln.split()
        n = int(vals[0])
        idx = [int(v) for v in vals[1:1 + n]]
        tris.extend((idx[0], idx[k], idx[k + 1]) for k in range(1, n - 1))
    faces = np.array(tris, dtype=np.int64).reshape(-1, 3)
    if len(faces) and (faces.min() < 0 or faces.max() >= nv):
        raise ValueError(f"{path}: face index out of range [0, {nv})")
    return trimesh.Trimesh(vertices=verts, faces=faces, process=False)


def load_mesh(path: str | Path) -> trimesh.Trimesh:
    """Load any mesh file as one Trimesh (scenes concatenated); ValueError if empty or unreadable."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file")
    try:
        if path.suffix.lower() == ".off":
            mesh = read_off(path)
        else:
            loaded = trimesh.load(path, process=False)
            if isinstance(loaded, trimesh.Scene):
                geoms = [g for g in loaded.dump() if isinstance(g, trimesh.Trimesh) and len(g.faces)]
                mesh = trimesh.util.concatenate(geoms) if geoms else trimesh.Trimesh()
            else:
                mesh = loaded
    except ValueError:
        raise
    except Exception as e:
        raise ValueError(f"{path}: cannot read mesh ({type(e).__name__}: {e})") from None
    if not isinstance(mesh, trimesh.Trimesh) or len(mesh.faces) == 0 or len(mesh.vertices) == 0:
        raise ValueError(f"{path}: mesh has no faces")
    return mesh
