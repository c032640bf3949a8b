"""Classification training data (paper section 5.1): each shape's octree at 12 rotations about
the up axis, for rotation augmentation in training and the 12-view vote at test time.

The rotated octrees are built once per record and cached beside the dataset
(:mod:`model.train.cache`); each rotation is normalised into the unit cube on its own, as an
uploaded shape is.
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

from ..octree import Octree, build_octree, validate
from ..octree.batch import merge_octrees
from ..octree.geometry import AXES, ROTATIONS, up_rotations
from ..octree.serialize import octree_from_arrays, octree_to_arrays
from .cache import cache_dir, load_derived
from .data import Sample, manifest_rows

CACHE_VERSION = 1
UP_AXES = AXES


def rotated_octrees(record, depth: int, kind: str, up: str, rotations: int = ROTATIONS) -> dict[str, np.ndarray]:
    """The octrees of a record's complete scan at ``rotations`` angles about ``up`` (cache content)."""
    out = {}
    for k, r in enumerate(up_rotations(up, rotations)):
        cloud = validate(record["points"] @ r.T, record["normals"] @ r.T)
        out.update(octree_to_arrays(build_octree(cloud, depth, adaptive=kind == "adaptive", neighbors=False),
                                    prefix=f"r{k}_"))
    return out


class ClassifySet:
    """The shapes of one split with their class labels and rotated octrees, in memory.
    ``samples[i].octree`` is rotation 0; ``rotations[i][k]`` rotation ``k``."""

    def __init__(self, data_dir: str | Path, split: str, classes: list[str], kind: str = "adaptive",
                 depth: int | None = None, limit: int | None = None, up: str = "y", workers: int = 1):
        if up not in UP_AXES:
            raise ValueError(f"up must be one of {', '.join(UP_AXES)}")
        data_dir = Path(data_dir)
        manifest, rows = manifest_rows(data_dir, split, depth, tuple(classes), limit)
        built = manifest["config"]["depth"]
        cache = cache_dir(data_dir, f"classify-{kind}",
                          {"v": CACHE_VERSION, "depth": built, "kind": kind, "up": up, "rotations": ROTATIONS})
        derive = functools.partial(rotated_octrees, depth=built, kind=kind, up=up)
        loaded = load_derived(data_dir, rows, cache, derive, (), workers)
        self.classes = list(classes)
        self.rotations: list[list[Octree]] = []
        self.samples: list[Sample] = []
        for r, (_, arrays) in zip(rows, loaded):
            trees = [octree_from_arrays(arrays, prefix=f"r{k}_", neighbors=False) for k in range(ROTATIONS)]
            self.rotations.append(trees)
            self.samples.append(Sample(r["category"], r["shape_id"], trees[0], np.zeros((0, 3), np.float32)))
        self.labels = np.array([self.classes.index(s.category) for s in self.samples], dtype=np.int64)
        self.depth = built
        self.latents = None

    def __len__(self) -> int:
        return len(self.samples)

    def batch(self, indices, rotation: int | np.ndarray = 0) -> tuple[Octree, np.ndarray]:
        """The merged octree (with neighbour tables) of ``indices`` at ``rotation`` (one index, or
        one per shape) and their labels."""
        rot = np.broadcast_to(np.asarray(rotation), (len(indices),))
        merged = merge_octrees([self.rotations[i][int(k)] for i, k in zip(indices, rot)], neighbors=True)
        return merged, self.labels[np.asarray(indices)]
