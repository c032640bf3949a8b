"""Shape-completion training data: each record's partial scans as input octrees, the complete
scan as the target octree, both in the partial scan's frame (:func:`model.octree.scan_frame`).

Inputs are built by :func:`model.octree.scan_octree`, the service's own code, once with the
scanner's normals and once with normals estimated from the points (a user's scan often has
none), so the model is trained on both.  The octrees of a record are built once and cached
beside the dataset (:mod:`model.train.cache`).
"""

from __future__ import annotations

import functools
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..octree import Normalization, Octree, build_octree, scan_frame, scan_octree, validate
from ..octree.batch import merge_octrees
from ..octree.pointcloud import normalization_of
from ..octree.serialize import octree_from_arrays, octree_to_arrays
from ..octree.symmetry import SHEET, find_mirror, mirror_cloud
from .cache import cache_dir, derived_arrays, load_derived, read_cached
from .data import LazySequence, Sample, check_stream, manifest_rows, pick_points

CACHE_VERSION = 1
NORMALS = ("given", "estimated")
KINDS = ("adaptive", "full")


@dataclass
class Variant:
    """One partial scan of a shape: input octrees per normals mode, target, points (truth cube)."""

    inputs: dict[str, Octree]          # NORMALS -> input octree (scan frame)
    target: Octree                     # the complete scan in the same frame
    partial: np.ndarray                # the partial points in the truth cube (the do-nothing floor)


def record_octrees(record, depth: int, kind: str, symmetry: float | None = None) -> dict[str, np.ndarray]:
    """Every octree of one record's completion samples, as arrays (the cache file's content).
    ``symmetry``: each scan whose mirror plane has at least this support is read with its mirror
    image (:mod:`model.octree.symmetry`, the service's ``symmetry``), inputs and target in the
    frame of both; None: the scans as they are."""
    adaptive = kind == "adaptive"
    complete = validate(record["points"], record["normals"])
    out: dict[str, np.ndarray] = {"scans": np.array(len(record["partial_offsets"]) - 1)}
    for j in range(int(out["scans"])):
        pts, nrm = record.partial(j)
        clouds = {mode: validate(pts, nrm if mode == "given" else None) for mode in NORMALS}
        if symmetry is not None and (mirror := find_mirror(pts)).supported(symmetry):
            clouds = {mode: mirror_cloud(cloud, mirror) for mode, cloud in clouds.items()}
        frame = scan_frame(clouds["given"].points)
        for mode, cloud in clouds.items():
            out.update(octree_to_arrays(scan_octree(cloud, depth, adaptive=adaptive, neighbors=False), prefix=f"s{j}_{mode}_"))
        target = build_octree(complete, depth, adaptive=adaptive, neighbors=False, normalization=frame)
        out.update(octree_to_arrays(target, prefix=f"s{j}_target_"))
    return out


class CompletionSet:
    """The completion samples of one split.  ``samples[i]`` is the evaluation view (scan 0,
    ``normals`` mode): its octree is the target, its points the truth in the complete shape's own
    cube (``truth_frame``), its ``partial`` the input points there; ``variants[i]`` every scan of
    shape ``i``.  Held in memory, or with ``stream`` read from the dataset and its cache each time
    a shape is asked for (the last ``stream`` shapes kept), for splits larger than memory: the
    same samples, the same batches."""

    def __init__(self, data_dir: str | Path, split: str, kind: str = "adaptive", points: int = 2048,
                 depth: int | None = None, limit: int | None = None, seed: int = 0,
                 categories: tuple[str, ...] | None = None, normals: str = "given", workers: int = 1,
                 stream: int = 0, symmetry: float | None = None):
        if kind not in KINDS:
            raise ValueError(f"kind must be one of {', '.join(KINDS)}")
        if normals not in NORMALS:
            raise ValueError(f"normals must be one of {', '.join(NORMALS)}")
        check_stream(stream)
        data_dir = Path(data_dir)
        manifest, rows = manifest_rows(data_dir, split, depth, categories, limit)
        if manifest["config"].get("partial_scans", 0) < 1:
            raise ValueError(f"{data_dir} has no partial scans; rebuild with --partial-scans 2")
        built = manifest["config"]["depth"]
        key = {"v": CACHE_VERSION, "depth": built, "kind": kind}
        if symmetry is not None:     # the mirror's rules are part of what the cached inputs are
            key["symmetry"] = symmetry
            key["sheet"] = SHEET
        cache = cache_dir(data_dir, f"completion-{kind}", key)
        keep = ("points", "partial_points", "partial_offsets")
        derive = functools.partial(record_octrees, depth=built, kind=kind, symmetry=symmetry)
        loaded = load_derived(data_dir, rows, cache, derive, ("points",) if stream else keep, workers,
                              derived=not stream, reduce=_truth_summary if stream else _with_summary)
        rng = np.random.default_rng(seed)
        self.normals = normals
        self._frames, self._picks = [], []           # per shape: the truth's cube and its picked points
        for (frame, count, _), _ in loaded:
            self._frames.append(frame)
            self._picks.append(pick_points(rng, count, points))
        self._rows = [(r["category"], r["shape_id"]) for r in rows]
        self._cached = [(cache / r["path"], r["sha256"]) for r in rows] if stream else None
        if stream:
            read = functools.lru_cache(maxsize=stream)(
                lambda i: self._shape(i, *derived_arrays(data_dir, rows[i], cache, derive, keep)))
            self.samples = LazySequence(len(rows), lambda i: read(i)[0])
            self.variants = LazySequence(len(rows), lambda i: read(i)[1])
        else:
            shapes = [self._shape(i, rec, arrays) for i, ((_, _, rec), arrays) in enumerate(loaded)]
            self.samples: list[Sample] = [s for s, _ in shapes]
            self.variants: list[list[Variant]] = [v for _, v in shapes]
        self.depth = built
        self.latents = None

    def _shape(self, i: int, rec: dict, arrays: dict) -> tuple[Sample, list[Variant]]:
        """Shape ``i``'s evaluation view and variants from its record's and cache's arrays."""
        truth = self._frames[i]
        variants = []
        off = rec["partial_offsets"]
        for j in range(int(arrays["scans"])):
            inputs = {m: octree_from_arrays(arrays, prefix=f"s{j}_{m}_", neighbors=False) for m in NORMALS}
            target = octree_from_arrays(arrays, prefix=f"s{j}_target_", neighbors=False)
            partial = truth.to_cube(rec["partial_points"][off[j]:off[j + 1]]).astype(np.float32)
            variants.append(Variant(inputs, target, partial))
        first = variants[0]
        category, shape_id = self._rows[i]
        cube = truth.to_cube(rec["points"][self._picks[i]]).astype(np.float32)
        return Sample(category, shape_id, first.target, cube, truth_frame=truth, partial=first.partial), variants

    def __len__(self) -> int:
        return len(self.samples)

    def pairs(self, indices, rng: np.random.Generator | None = None) -> tuple[Octree, Octree]:
        """Merged (input, target) octrees with neighbour tables.  With ``rng``, each shape's scan
        and normals mode are drawn at random (training); without, the evaluation view."""
        inputs, targets = [], []
        for i in indices:
            source, target = self._drawn(i, rng) if rng is not None else (self.scan(i), self.variants[i][0].target)
            inputs.append(source)
            targets.append(target)
        return merge_octrees(inputs, neighbors=True), merge_octrees(targets, neighbors=True)

    def _drawn(self, i: int, rng: np.random.Generator) -> tuple[Octree, Octree]:
        """The (input, target) octrees of a scan and normals mode of shape ``i`` drawn from ``rng``;
        a streamed set reads only those two octrees from the cache."""
        def draw(scans: int) -> tuple[int, str]:
            return int(rng.integers(scans)), NORMALS[int(rng.integers(len(NORMALS)))]

        if self._cached is not None:
            def read(f) -> tuple[Octree, Octree]:
                j, mode = draw(int(f["scans"]))
                return (octree_from_arrays(f, prefix=f"s{j}_{mode}_", neighbors=False),
                        octree_from_arrays(f, prefix=f"s{j}_target_", neighbors=False))

            state = rng.bit_generator.state       # a failed read draws again from the same state
            if (pair := read_cached(*self._cached[i], read)) is not None:
                return pair
            rng.bit_generator.state = state
        options = self.variants[i]
        j, mode = draw(len(options))
        return options[j].inputs[mode], options[j].target

    def scan(self, i: int) -> Octree:
        """The input octree of sample ``i``'s evaluation view (scan 0, the set's normals mode)."""
        return self.variants[i][0].inputs[self.normals]

    def batch(self, indices) -> tuple[Octree, np.ndarray]:
        """The merged target octree of the evaluation view and the truth points (B, P, 3)."""
        _, target = self.pairs(indices)
        return target, np.stack([self.samples[i].points for i in indices])


def _truth_summary(rec: dict) -> tuple[Normalization, int, None]:
    """What a streamed set holds of a record: its truth's cube and its number of points."""
    return normalization_of(rec["points"]), len(rec["points"]), None


def _with_summary(rec: dict) -> tuple[Normalization, int, dict]:
    """What a set held in memory keeps of a record: the summary and the arrays themselves."""
    return normalization_of(rec["points"]), len(rec["points"]), rec


def truth_view(sample: Sample, cube_points: np.ndarray) -> np.ndarray:
    """Decoded points (cube of ``sample.octree``'s frame) in the sample's truth cube."""
    if sample.truth_frame is None:
        return cube_points
    return sample.truth_frame.to_cube(sample.octree.normalizations[0].to_world(cube_points))
