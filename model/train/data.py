"""Training batches from a built dataset: records' octrees merged per batch, plus target points."""

from __future__ import annotations

import json
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..data.dataset import load_record
from ..octree import Normalization, Octree
from ..octree.batch import merge_octrees
from ..octree.serialize import octree_from_arrays


@dataclass
class Sample:
    """One shape: its octree (input and target; the target for completion) and target points in
    unit-cube coordinates (the octree's cube, or ``truth_frame``'s when set)."""

    category: str
    shape_id: str
    octree: Octree
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


def _load_sample(path: Path, octree: str, images: bool) -> tuple[Octree, np.ndarray, np.ndarray | None]:
    """One record's octree, its points in the octree's cube and (with ``images``) its renders;
    ValueError naming the file if it is missing, damaged or has no renders."""
    try:
        rec = load_record(path)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:   # missing, truncated or foreign file
        raise ValueError(f"{path} is missing or damaged ({type(exc).__name__}); "
                         "rerun python -m model.data build to repair the dataset") from None
    tree = octree_from_arrays(rec.arrays, prefix=f"{octree}_", neighbors=False)
    cube = tree.normalizations[0].to_cube(rec["points"])
    views = None
    if images:
        views = rec["images"]
        if views.ndim != 4 or views.shape[-1] != 4 or len(views) == 0:
            raise ValueError(f"{path} has no RGBA renders; rebuild with --views 24")
    return tree, cube, views


def _load_star(args):
    return _load_sample(*args)


def process_map(fn, jobs: list, workers: int = 1, chunksize: int = 4) -> list:
    """``[fn(j) for j in jobs]``, in ``workers`` forked processes when more than one (``fn`` a
    module-level function or a partial of one); the results in the order of ``jobs``."""
    if workers <= 1 or len(jobs) <= 1:
        return [fn(j) for j in jobs]
    import multiprocessing as mp
    with mp.get_context("fork").Pool(min(workers, len(jobs))) as pool:
        return pool.map(fn, jobs, chunksize=chunksize)


class RecordSet:
    """The records of one split of a dataset, held in memory (octree arrays and a point subset).

    ``workers`` > 1 reads the records in that many processes (the same samples as one)."""

    def __init__(self, data_dir: str | Path, split: str, octree: str = "adaptive",
                 points: int = 2048, depth: int | None = None, limit: int | None = None, seed: int = 0,
                 images: bool = False, categories: tuple[str, ...] | None = None, workers: int = 1):
        data_dir = Path(data_dir)
        _, rows = manifest_rows(data_dir, split, depth, categories, limit)
        rng = np.random.default_rng(seed)
        loaded = process_map(_load_star, [(data_dir / r["path"], octree, images) for r in rows], workers, 8)
        self.samples: list[Sample] = []
        for r, (tree, cube, views) in zip(rows, loaded):
            pick = rng.choice(len(cube), size=points, replace=len(cube) < points)
            self.samples.append(Sample(r["category"], r["shape_id"], tree, cube[pick].astype(np.float32), views))
        self.depth = self.samples[0].octree.depth
        self.latents = None        # optional per-shape target codes (a tensor), set by a task

    def __len__(self) -> int:
        return len(self.samples)

    def batch(self, indices) -> tuple[Octree, np.ndarray]:
        """The merged octree (with neighbour tables) and stacked points (B, P, 3) of ``indices``."""
        chosen = [self.samples[i] for i in indices]
        return merge_octrees([s.octree for s in chosen], neighbors=True), np.stack([s.points for s in chosen])
