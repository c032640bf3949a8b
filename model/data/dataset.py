"""Dataset build: one compact .npz record per shape and a manifest, resumable and crash-safe.

A record holds the complete virtual scan (points, normals), the adaptive and the full octree at
the dataset's depth, 3D-R2N2-style renders with their cameras, and partial scans for shape
completion.  Shapes come from the procedural categories, from a real dataset layout
(ModelNet40, ShapeNetCore.v2, 3D-R2N2) or from a plain folder of mesh files (all of them test
shapes: the models evaluated on one's own meshes); every source gives the same record format.
"""

from __future__ import annotations

import hashlib
import io
import json
import multiprocessing as mp
import re
import shutil
from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image
from tqdm import tqdm

from ..files import TEMP_PREFIX, npz_bytes, write_atomic
from ..octree import build_octree
from ..octree.serialize import octree_from_arrays, octree_to_arrays
from .layouts import iter_mesh_folder, iter_modelnet40, iter_r2n2, iter_shapenet, load_mesh, y_up
from .partial import partial_from_scan
from .render import metadata_row, render_views
from .scanner import scan_detailed
from .shapes import CATEGORIES, check_category, generate, split_of, stable_hash

RECORD_VERSION = 1
SOURCES = ("procedural", "modelnet40", "shapenet", "r2n2", "folder")


@dataclass(frozen=True)
class BuildConfig:
    """What every record of a dataset is built with; stored in the manifest and each record."""

    depth: int = 6
    views: int = 24
    render_size: int = 137
    partial_scans: int = 2
    scan_resolution: int = 160
    seed: int = 0
    generator: int = 1                               # procedural shapes: model.data.shapes.GENERATORS
    up: str = "y"                                    # real meshes: their up axis, turned y-up (layouts.y_up)

    def settings(self) -> dict:
        """The settings as the manifest stores them; the first generator and the y axis up are
        not named, so the datasets built before either setting existed keep their manifests and
        fingerprints."""
        d = asdict(self)
        if d["generator"] == 1:
            del d["generator"]
        if d["up"] == "y":
            del d["up"]
        return d

    def fingerprint(self) -> str:
        return hashlib.sha256(json.dumps(self.settings(), sort_keys=True).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class ShapeTask:
    """One shape to build: where its mesh (and, for 3D-R2N2, its renders) come from."""

    source: str
    category: str
    shape_id: str
    split: str
    index: int = -1                                  # procedural shapes
    mesh_path: str = ""                              # real datasets
    image_paths: tuple[str, ...] = ()                # 3D-R2N2 renders
    cameras: tuple[tuple[float, ...], ...] = field(default=())

    @property
    def relpath(self) -> str:
        return f"records/{self.category}/{self.shape_id}.npz"


def procedural_tasks(per_category: int, seed: int = 0,
                     categories: tuple[str, ...] = CATEGORIES) -> list[ShapeTask]:
    """The first ``per_category`` generated shapes of each category."""
    return [ShapeTask("procedural", check_category(c), f"{c}_{seed}_{i:05d}", split_of(c, i, seed), index=i)
            for c in categories for i in range(per_category)]


def layout_tasks(source: str, root: str, per_category: int | None = None,
                 categories: tuple[str, ...] | None = None, shapenet_root: str | None = None) -> list[ShapeTask]:
    """Tasks for the shapes of a real dataset layout found under ``root``."""
    if source == "modelnet40":
        recs = [(r, (), ()) for r in iter_modelnet40(root)]
    elif source == "shapenet":
        recs = [(r, (), ()) for r in iter_shapenet(root)]
    elif source == "folder":
        recs = [(r, (), ()) for r in iter_mesh_folder(root)]
    elif source == "r2n2":
        recs = [(r, tuple(str(p) for p in r.image_paths), tuple(tuple(_row(m)) for m in r.metadata))
                for r in iter_r2n2(root, shapenet_root=shapenet_root)]
        missing = [r.shape_id for r, _, _ in recs if r.mesh_path is None]
        if missing:
            raise ValueError(f"{len(missing)} 3D-R2N2 shapes have no mesh (e.g. {missing[0]}); "
                             "pass the ShapeNetCore.v2 root with --shapenet-root")
    else:
        raise ValueError(f"unknown source {source!r}; use one of {', '.join(SOURCES)}")
    tasks, seen = [], {}
    for rec, images, cameras in recs:
        if categories and rec.category not in categories:
            continue
        seen[rec.category] = seen.get(rec.category, 0) + 1
        if per_category is not None and seen[rec.category] > per_category:
            continue
        tasks.append(ShapeTask(source, rec.category, rec.shape_id, rec.split,
                               mesh_path=str(rec.mesh_path), image_paths=images, cameras=cameras))
    return tasks


def _row(meta) -> list[float]:
    return [meta.azimuth, meta.elevation, meta.in_plane_rotation, meta.distance_ratio, meta.fov]


def unit_mesh(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """The mesh centred with its longest bounding-box edge 1 (ShapeNet's model_normalized
    convention), and (centre, scale) that map it back."""
    v = np.asarray(mesh.vertices, dtype=np.float64)
    lo, hi = v.min(0), v.max(0)
    scale = float((hi - lo).max())
    if not np.isfinite(scale) or scale <= 0:
        raise ValueError("the mesh has no extent")
    centre = (lo + hi) / 2
    out = trimesh.Trimesh(vertices=(v - centre) / scale, faces=np.asarray(mesh.faces), process=False)
    return out, np.r_[centre, scale]


def scan_shape(task: ShapeTask, cfg: BuildConfig):
    """A shape's unit mesh, its normalisation, its complete virtual scan (with each point's view
    and image position) and the random stream the rest of its record is drawn from: the first
    steps of :func:`build_record`, also used to cut new partial scans from a built dataset's shapes."""
    rng = np.random.default_rng(stable_hash("record", task.source, task.category, task.shape_id, cfg.seed))
    mesh = (generate(task.category, task.index, cfg.seed, cfg.generator) if task.source == "procedural"
            else y_up(load_mesh(task.mesh_path), cfg.up))
    mesh, mesh_norm = unit_mesh(mesh)
    return mesh, mesh_norm, scan_detailed(mesh, resolution=cfg.scan_resolution, rng=rng), rng


def build_record(task: ShapeTask, cfg: BuildConfig) -> dict[str, np.ndarray]:
    """All arrays of one shape's record (see the module docstring)."""
    mesh, mesh_norm, full_scan, rng = scan_shape(task, cfg)
    cloud = (full_scan.points, full_scan.normals)
    adaptive = build_octree(cloud, cfg.depth, adaptive=True, neighbors=False)
    full = build_octree(cloud, cfg.depth, adaptive=False, neighbors=False)
    if task.source == "r2n2":
        images, cameras = _read_r2n2_views(task)
    else:
        images, cams = render_views(mesh, n_views=cfg.views, rng=rng, size=cfg.render_size)
        cameras = np.array([metadata_row(c) for c in cams], dtype=np.float32).reshape(-1, 5)
    partial_pts, partial_nrm, offsets = [], [], [0]
    for _ in range(cfg.partial_scans):
        p, n, _ = partial_from_scan(full_scan, rng)
        partial_pts.append(p)
        partial_nrm.append(n)
        offsets.append(offsets[-1] + len(p))
    return {
        "version": np.array(RECORD_VERSION),
        "config": np.array(cfg.fingerprint()),
        "category": np.array(task.category), "shape_id": np.array(task.shape_id),
        "split": np.array(task.split), "source": np.array(task.source),
        "mesh_normalization": mesh_norm,
        "points": full_scan.points.astype(np.float32), "normals": full_scan.normals.astype(np.float32),
        "images": images, "cameras": cameras,
        "partial_points": np.concatenate(partial_pts) if partial_pts else np.zeros((0, 3), np.float32),
        "partial_normals": np.concatenate(partial_nrm) if partial_nrm else np.zeros((0, 3), np.float32),
        "partial_offsets": np.array(offsets, dtype=np.int64),
        **octree_to_arrays(adaptive, prefix="adaptive_"),
        **octree_to_arrays(full, prefix="full_"),
    }


def _read_r2n2_views(task: ShapeTask) -> tuple[np.ndarray, np.ndarray]:

    images = np.stack([np.asarray(Image.open(p).convert("RGBA")) for p in task.image_paths])
    return images, np.array(task.cameras, dtype=np.float32).reshape(-1, 5)


def write_npz_atomic(path: Path, arrays: dict[str, np.ndarray]) -> str:
    """Write a compressed .npz (:func:`model.files.npz_bytes`) beside ``path`` under a temporary
    name, then rename; returns sha256."""
    data = npz_bytes(arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, data, fsync=True)
    return hashlib.sha256(data).hexdigest()


@dataclass
class RecordSummary:
    """One manifest row."""

    category: str
    shape_id: str
    split: str
    path: str
    sha256: str
    points: int
    adaptive_nodes: int
    full_nodes: int


def _summary(task: ShapeTask, path: Path, sha: str, arrays) -> RecordSummary:
    return RecordSummary(task.category, task.shape_id, task.split, task.relpath, sha,
                         int(len(arrays["points"])), int(len(arrays["adaptive_key"])),
                         int(len(arrays["full_key"])))


def _existing(out: Path, task: ShapeTask, cfg: BuildConfig) -> RecordSummary | None:
    """The summary of a finished record built with the same config, or None to (re)build it."""
    path = out / task.relpath
    if not path.is_file():
        return None
    try:
        data = path.read_bytes()
        with np.load(io.BytesIO(data)) as f:
            if str(f["config"]) != cfg.fingerprint() or int(f["version"]) != RECORD_VERSION:
                return None
            return _summary(task, path, hashlib.sha256(data).hexdigest(), f)
    except Exception:  # an unreadable file is rebuilt
        return None


def _work(args: tuple[str, ShapeTask, BuildConfig]) -> RecordSummary:
    out, task, cfg = args
    arrays = build_record(task, cfg)
    path = Path(out) / task.relpath
    sha = write_npz_atomic(path, arrays)
    return _summary(task, path, sha, arrays)


@dataclass(frozen=True)
class Shard:
    """Part ``index`` of ``count`` (0 <= index < count): the shapes whose stable hash falls in it.

    Shape-level and independent of the task list's order, so N independent jobs (a Kubernetes
    Indexed Job, a SLURM array) build disjoint parts whose union is the whole dataset.
    """

    index: int
    count: int

    @classmethod
    def parse(cls, text: str) -> Shard:
        m = re.fullmatch(r"(\d+)/(\d+)", text.strip())
        if not m or not 0 <= int(m.group(1)) < int(m.group(2)):
            raise ValueError(f"--shard must be K/N with 0 <= K < N (e.g. 0/4), got {text!r}")
        return cls(int(m.group(1)), int(m.group(2)))

    def holds(self, task: ShapeTask) -> bool:
        return stable_hash("shard", task.source, task.category, task.shape_id) % self.count == self.index

    @property
    def manifest_name(self) -> str:
        return f"manifest.shard-{self.index}-of-{self.count}.json"


def _manifest(cfg: BuildConfig, done: list[RecordSummary], shard: Shard | None = None) -> dict:
    done = sorted(done, key=lambda s: (s.category, s.shape_id))
    manifest = {
        "version": RECORD_VERSION,
        "config": cfg.settings(),
        "config_fingerprint": cfg.fingerprint(),
        "splits": {sp: sum(1 for s in done if s.split == sp) for sp in ("train", "val", "test")},
        "records": [asdict(s) for s in done],
    }
    if shard is not None:
        manifest["shard"] = {"index": shard.index, "count": shard.count}
    return manifest


def build_dataset(out: str | Path, tasks: list[ShapeTask], cfg: BuildConfig, workers: int = 1,
                  progress: bool = True, shard: Shard | None = None, keep: list[ShapeTask] = ()) -> dict:
    """Build every task's record under ``out`` (skipping finished ones) and write the manifest;
    with ``shard``, only that shard's records and ``manifest.shard-K-of-N.json`` (see :func:`merge_shards`).
    ``keep``: tasks not to build, listed in the manifest too where ``out`` already holds their
    finished records (a build of some splits keeps the others an earlier build made)."""

    if shard is not None:
        tasks = [t for t in tasks if shard.holds(t)]
        keep = [t for t in keep if shard.holds(t)]
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    for tmp in out.rglob(TEMP_PREFIX + "*"):  # leftovers of a killed build
        tmp.unlink()
    done, todo = [], []
    for t in tasks:
        s = _existing(out, t, cfg)
        (done if s is not None else todo).append(s if s is not None else t)
    bar = tqdm(total=len(tasks), initial=len(done), desc="shapes", unit="shape", disable=not progress)
    jobs = [(str(out), t, cfg) for t in todo]
    if workers > 1 and len(jobs) > 1:

        with mp.get_context("fork").Pool(workers) as pool:
            for s in pool.imap_unordered(_work, jobs):
                done.append(s)
                bar.update()
    else:
        for j in jobs:
            done.append(_work(j))
            bar.update()
    bar.close()
    kept = [s for s in (_existing(out, t, cfg) for t in keep) if s is not None]
    manifest = _manifest(cfg, done + kept, shard)
    name = shard.manifest_name if shard is not None else "manifest.json"
    write_atomic(out / name, (json.dumps(manifest, indent=1) + "\n").encode())
    return manifest


def merge_shards(out: str | Path, shard_dirs: list[str | Path]) -> dict:
    """Join shard builds into one dataset under ``out``: checks that every shard of one N is there
    exactly once with the same build config, that no shape appears twice, and that every record
    file exists with its manifest's sha256 (copying records that live in other folders); then
    writes ``out/manifest.json``, identical to the one a single build would write."""

    out = Path(out)
    found: dict[int, tuple[Path, dict]] = {}
    count = fingerprint = None
    for d in map(Path, shard_dirs):
        for path in sorted(d.glob("manifest.shard-*-of-*.json")):
            try:
                m = json.loads(path.read_text())
                sh = m["shard"]
                [(r["category"], r["shape_id"], r["path"], r["sha256"]) for r in m["records"]]
            except (ValueError, KeyError, TypeError) as exc:
                raise ValueError(f"{path}: not a shard manifest ({type(exc).__name__}: {exc})") from None
            if count is None:
                count, fingerprint = sh.get("count"), m.get("config_fingerprint")
            if sh.get("count") != count:
                raise ValueError(f"{path}: shard of {sh.get('count')} parts, others are of {count}")
            if m.get("config_fingerprint") != fingerprint or m.get("version") != RECORD_VERSION:
                raise ValueError(f"{path}: built with another config or record version than the other shards")
            if sh.get("index") in found:
                raise ValueError(f"{path}: shard {sh.get('index')} also in {found[sh['index']][0]}")
            found[sh["index"]] = (path, m)
    if not found:
        raise ValueError(f"no shard manifests (manifest.shard-K-of-N.json) in {', '.join(map(str, shard_dirs))}")
    missing = sorted(set(range(count)) - set(found))
    if missing:
        raise ValueError(f"shards {missing} of {count} are missing; build them with --shard K/{count}")
    rows, seen = [], set()
    for index in sorted(found):
        path, m = found[index]
        for r in m["records"]:
            key = (r["category"], r["shape_id"])
            if key in seen:
                raise ValueError(f"{path}: shape {key[1]} is in two shards")
            seen.add(key)
            src, dst = path.parent / r["path"], out / r["path"]
            if not src.is_file():
                raise ValueError(f"{src}: missing (listed in {path.name})")
            if hashlib.sha256(src.read_bytes()).hexdigest() != r["sha256"]:
                raise ValueError(f"{src}: sha256 differs from {path.name}; rebuild that shard")
            if src.resolve() != dst.resolve():
                dst.parent.mkdir(parents=True, exist_ok=True)
                shutil.copyfile(src, dst)
            rows.append(RecordSummary(**r))
    cfg = BuildConfig(**found[min(found)][1]["config"])
    manifest = _manifest(cfg, rows)
    write_atomic(out / "manifest.json", (json.dumps(manifest, indent=1) + "\n").encode())
    return manifest


@dataclass
class ShapeRecord:
    """A loaded record: arrays plus helpers to rebuild its octrees and partial scans."""

    arrays: dict[str, np.ndarray]

    def __getitem__(self, name: str) -> np.ndarray:
        return self.arrays[name]

    def octree(self, kind: str = "adaptive", neighbors: bool = True):
        if kind not in ("adaptive", "full"):
            raise ValueError("kind must be 'adaptive' or 'full'")
        return octree_from_arrays(self.arrays, prefix=f"{kind}_", neighbors=neighbors)

    def partial(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        o = self.arrays["partial_offsets"]
        return self.arrays["partial_points"][o[i]:o[i + 1]], self.arrays["partial_normals"][o[i]:o[i + 1]]


def load_record(path: str | Path) -> ShapeRecord:
    """Read one record written by :func:`build_dataset`."""
    with np.load(path) as f:
        return ShapeRecord({k: f[k] for k in f.files})
