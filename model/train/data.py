"""Training batches from a built dataset: records' octrees merged per batch, plus target points."""

from __future__ import annotations

import functools
import json
import multiprocessing as mp
import zipfile
import zlib
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..octree import Normalization, Octree
from ..octree.batch import merge_octrees
from ..octree.serialize import octree_from_arrays


@dataclass
class Sample:
    """One shape: its octree (input and target; the target for completion) and target points in
    unit-cube coordinates (the octree's cube, or ``truth_frame``'s when set)."""

    category: str
    shape_id: str
    octree: Octree | None                # None in a renders-only set
    points: np.ndarray
    images: np.ndarray | None = None     # (V, H, W, 4) uint8 renders, when loaded
    truth_frame: Normalization | None = None   # completion: the cube ``points`` are in (else octree's)
    partial: np.ndarray | None = None    # completion: the input scan's points in that cube


def manifest_rows(data_dir: Path, split: str, depth: int | None = None,
                  categories: tuple[str, ...] | None = None, limit: int | None = None) -> tuple[dict, list[dict]]:
    """A dataset's manifest and its rows of ``split`` (of ``categories``, at most ``limit``);
    FileNotFoundError without a manifest, ValueError on a depth mismatch or no rows."""
    manifest_path = data_dir / "manifest.json"
    if not manifest_path.is_file():
        raise FileNotFoundError(f"{manifest_path} not found: build the dataset with python -m model.data build")
    manifest = json.loads(manifest_path.read_text())
    if depth is not None and manifest["config"]["depth"] != depth:
        raise ValueError(f"the dataset was built at depth {manifest['config']['depth']}, not {depth}")
    rows = [r for r in manifest["records"] if r["split"] == split
            and (not categories or r["category"] in categories)][:limit]
    if not rows:
        which = f" of categories {', '.join(categories)}" if categories else ""
        raise ValueError(f"no records of split {split!r}{which} in {data_dir}")
    return manifest, rows


def _damaged(path: Path, exc: Exception) -> ValueError:
    return ValueError(f"{path} is missing or damaged ({type(exc).__name__}); "
                      "rerun python -m model.data build to repair the dataset")


READ_ERRORS = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error)
"""What reading a missing, truncated, damaged or foreign .npz file raises."""


def _load_sample(path: Path, octree: str | None, images: bool) -> tuple[Octree | None, np.ndarray, np.ndarray | None]:
    """One record's octree, its points in the octree's cube (with ``octree`` None: neither, no
    points) and (with ``images``) its renders; ValueError naming the file if it is missing,
    damaged or has no renders."""
    tree, cube = None, np.empty((0, 3), np.float32)
    try:
        with np.load(path) as rec:          # only the arrays used are read and decompressed
            if octree is not None:
                tree = octree_from_arrays(rec, prefix=f"{octree}_", neighbors=False)
                cube = tree.normalizations[0].to_cube(rec["points"])
            views = (rec["images"] if "images" in rec.files else np.empty(0)) if images else None
    except READ_ERRORS as exc:
        raise _damaged(path, exc) from None
    if views is not None and (views.ndim != 4 or views.shape[-1] != 4 or len(views) == 0):
        raise ValueError(f"{path} has no RGBA renders; rebuild with --views 24")
    return tree, cube, views


def point_count(path: Path) -> int:
    """How many points a record holds, read from its array's header alone; ValueError as
    :func:`_load_sample`."""
    try:
        with zipfile.ZipFile(path) as z, z.open("points.npy") as f:
            version = np.lib.format.read_magic(f)
            read = np.lib.format.read_array_header_1_0 if version == (1, 0) else np.lib.format.read_array_header_2_0
            return int(read(f)[0][0])
    except READ_ERRORS as exc:
        raise _damaged(path, exc) from None


def _load_star(args):
    return _load_sample(*args)


def process_map(fn, jobs: list, workers: int = 1, chunksize: int = 4) -> list:
    """``[fn(j) for j in jobs]``, in ``workers`` forked processes when more than one (``fn`` a
    module-level function or a partial of one); the results in the order of ``jobs``."""
    if workers <= 1 or len(jobs) <= 1:
        return [fn(j) for j in jobs]
    with mp.get_context("fork").Pool(min(workers, len(jobs))) as pool:
        return pool.map(fn, jobs, chunksize=chunksize)


def check_stream(stream) -> None:
    """ValueError unless ``stream`` is 0 (a split held in memory) or a number of shapes to keep."""
    if isinstance(stream, bool) or not isinstance(stream, int) or stream < 0:
        raise ValueError(f"stream must be 0 (the whole split in memory) or a number of shapes, not {stream!r}")


class LazySequence(Sequence):
    """A read-only sequence of ``n`` items made by ``item(i)`` when asked for."""

    def __init__(self, n: int, item):
        self._n, self._item = n, item

    def __len__(self) -> int:
        return self._n

    def __getitem__(self, i):
        if isinstance(i, slice):
            return [self._item(k) for k in range(*i.indices(self._n))]
        if not -self._n <= i < self._n:
            raise IndexError(i)
        return self._item(i % self._n)


class RecordSet:
    """The records of one split of a dataset (octree arrays, a point subset and optionally the
    renders; with ``octree`` None the renders alone: samples without octree or points): held in
    memory, or with ``stream`` read from the dataset each time a shape is asked for (the last
    ``stream`` shapes kept), for splits larger than memory: the same samples.

    ``workers`` > 1 reads the records in that many processes (the same samples as one)."""

    def __init__(self, data_dir: str | Path, split: str, octree: str | None = "adaptive",
                 points: int = 2048, depth: int | None = None, limit: int | None = None, seed: int = 0,
                 images: bool = False, categories: tuple[str, ...] | None = None, workers: int = 1,
                 stream: int = 0):
        check_stream(stream)
        data_dir = Path(data_dir)
        manifest, rows = manifest_rows(data_dir, split, depth, categories, limit)
        rng = np.random.default_rng(seed)
        self.depth = int(manifest["config"]["depth"])
        self.latents = None        # optional per-shape target codes (a tensor), set by a task
        self.record_sha256 = [r["sha256"] for r in rows]
        paths = [data_dir / r["path"] for r in rows]
        if octree is None and not images:
            raise ValueError("a record set without octrees holds the renders: give images=True")
        def pick(count: int) -> np.ndarray:          # a renders-only set keeps no points
            return pick_points(rng, count, points) if octree is not None else np.empty(0, np.int64)

        if stream:
            counts = process_map(point_count, paths, workers, 32) if octree is not None else [0] * len(paths)
            picks = [pick(n) for n in counts]

            def read(i: int) -> Sample:
                tree, cube, views = _load_sample(paths[i], octree, images)
                return Sample(rows[i]["category"], rows[i]["shape_id"], tree,
                              cube[picks[i]].astype(np.float32), views)

            self.samples: Sequence[Sample] = LazySequence(len(rows), functools.lru_cache(maxsize=stream)(read))
            return
        loaded = process_map(_load_star, [(p, octree, images) for p in paths], workers, 8)
        self.samples = [Sample(r["category"], r["shape_id"], tree,
                               cube[pick(len(cube))].astype(np.float32), views)
                        for r, (tree, cube, views) in zip(rows, loaded)]

    def __len__(self) -> int:
        return len(self.samples)

    def batch(self, indices) -> tuple[Octree, np.ndarray]:
        """The merged octree (with neighbour tables) and stacked points (B, P, 3) of ``indices``."""
        chosen = [self.samples[i] for i in indices]
        return merge_octrees([s.octree for s in chosen], neighbors=True), np.stack([s.points for s in chosen])


def pick_points(rng: np.random.Generator, count: int, points: int) -> np.ndarray:
    """Which ``points`` of a record's ``count`` a sample keeps (with repeats when too few)."""
    return rng.choice(count, size=points, replace=count < points)
