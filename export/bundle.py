"""The model bundle: a folder of ONNX graphs plus ``model.json``, verified before anything runs.

Layout: ``BUNDLE/model.json`` and one ``<graph>.onnx`` per graph it lists.  ``model.json`` holds
the format version, task, name and version, the octree settings, the input and output spec,
category names, every graph's file, sha256 and input/output names, dtypes and shapes (str axes
are dynamic: "nodes", "64*batch", "8*splits"), the export settings, the checkpoint's provenance
and its evaluation.  Invariant: a :class:`Bundle` returned by :func:`load_bundle` has every graph
its task needs, each file's sha256 matches, and its format is one this code reads.
No torch here: the service imports this module.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from enum import StrEnum
from pathlib import Path

from model.decode import empty_bias_of
from model.files import sha256_file
from model.image.frame import ImageSpec
from model.image.mask import MaskSpec
from model.octree.build import MAX_BUILD_DEPTH

BUNDLE_FORMAT = 2
"""The newest bundle layout this code reads and writes; newer bundles are refused.  2 adds guided
decoders (``octree.guided``), which a format-1 reader could not run, so bundles without them are
still written as format 1."""
MANIFEST = "model.json"
class Task(StrEnum):
    """What a bundle serves (``model.json``'s ``task``)."""

    IMAGE_TO_SHAPE = "image-to-shape"
    COMPLETION = "completion"
    AUTOENCODER = "autoencoder"
    CLASSIFY = "classify"


TASKS = tuple(Task)
BUNDLE_TASKS = {"image": Task.IMAGE_TO_SHAPE, "autoencoder": Task.AUTOENCODER, "completion": Task.COMPLETION,
                "classify": Task.CLASSIFY}
"""Training task (``python -m model.train TASK``) -> the bundle task its export serves."""
SERVED_IN = {**BUNDLE_TASKS, "foreground": Task.IMAGE_TO_SHAPE, "refine": Task.IMAGE_TO_SHAPE}
"""Training task -> the bundle that serves its network (the foreground networks ride in image bundles)."""
DTYPES = ("float32", "int64")


class BundleError(ValueError):
    """A bundle that cannot be used; the message names the file and what is wrong."""


@dataclass(frozen=True)
class GraphSpec:
    """One graph of the bundle: its file, checksum and input/output (dtype, shape) by name."""

    name: str
    file: str
    sha256: str
    inputs: dict[str, tuple[str, tuple]]
    outputs: dict[str, tuple[str, tuple]]

    def to_json(self) -> dict:
        return {"file": self.file, "sha256": self.sha256,
                "inputs": {k: {"dtype": t, "shape": list(s)} for k, (t, s) in self.inputs.items()},
                "outputs": {k: {"dtype": t, "shape": list(s)} for k, (t, s) in self.outputs.items()}}


@dataclass(frozen=True)
class OctreeSpec:
    """The octree the decoder grows (and the encoder reads): depths, statuses and planes."""

    depth: int
    full_depth: int
    adaptive_depth: int
    adaptive: bool                       # input octrees of the encoder are adaptive (else full)
    classes: dict[int, int]              # status classes per decoded depth (2 or 3)
    planes: tuple[int, ...]              # depths whose predict graph outputs planes
    latent: int
    threshold: float | None = None       # build threshold (finest voxels) of the encoder's input octrees
    signal: str = "all"                  # encoder signal: every depth ('all') or the 'finest'
    guided: bool = False                 # output-guided skip connections: the encoder also outputs
                                         # skip_d and each decoder_predict_d reads skip, skip_index


@dataclass(frozen=True)
class Bundle:
    """A verified bundle (see the module invariant)."""

    path: Path
    format: int
    task: str
    name: str
    version: str
    octree: OctreeSpec
    input: dict
    output: dict
    categories: list[str]
    graphs: dict[str, GraphSpec]
    meta: dict = field(repr=False)        # the whole model.json (export settings, provenance, evaluation)
    keep_scan_bias: dict[int, float] = field(default_factory=dict)
    """The empty-class bias per depth a completion decodes with when its output keeps the scan
    (``output.keep_scan``, chosen on the validation split by ``python -m research.calibrate --keep-scan``)."""

    def file(self, graph: str) -> Path:
        return self.path / self.graphs[graph].file

    def image_spec(self) -> ImageSpec:
        """The preprocessing an image-to-shape bundle's encoder was trained with."""
        if self.input.get("kind") != "image":
            raise BundleError(f"{self.path}: a {self.task} bundle takes no image")
        return ImageSpec.from_dict(self.input["image"])

    def mask_spec(self) -> MaskSpec | None:
        """How the bundle's foreground network takes images; None when it has none."""
        fg = self.input.get("foreground")
        if "foreground" not in self.graphs or not isinstance(fg, dict):
            return None
        spec = MaskSpec.from_dict(fg)
        if spec.crop_size and "foreground_refine" not in self.graphs:
            raise BundleError(f"{self.path}: model.json gives the refinement's crop_size, but the bundle has no "
                              "foreground_refine graph")
        return spec

    def checksums(self) -> dict[str, str]:
        return {g.file: g.sha256 for g in self.graphs.values()}


def required_graphs(task: str, octree: OctreeSpec) -> list[str]:
    """The graphs a bundle of ``task`` must hold."""
    decoder = ["decoder_start"] + [f"decoder_predict_{d}" for d in range(octree.full_depth, octree.depth + 1)] \
        + [f"decoder_expand_{d}" for d in range(octree.full_depth, octree.depth)]
    return {Task.IMAGE_TO_SHAPE: ["image_encoder", *decoder],
            Task.COMPLETION: ["octree_encoder", *decoder],
            Task.AUTOENCODER: ["octree_encoder", *decoder],
            Task.CLASSIFY: ["octree_encoder", "classifier_head"]}[task]


def _get(obj: dict, key: str, kind, where: str):
    if not isinstance(obj, dict) or key not in obj:
        raise BundleError(f"{where}: missing {key!r}")
    value = obj[key]
    if kind is int and isinstance(value, bool) or not isinstance(value, kind):
        raise BundleError(f"{where}: {key!r} must be {getattr(kind, '__name__', kind)}, got {value!r}")
    return value


def _io(spec: dict, where: str) -> dict[str, tuple[str, tuple]]:
    if not isinstance(spec, dict) or not spec:
        raise BundleError(f"{where}: must be a non-empty object of name -> {{dtype, shape}}")
    out = {}
    for name, item in spec.items():
        dtype = _get(item, "dtype", str, f"{where}.{name}")
        shape = _get(item, "shape", list, f"{where}.{name}")
        if dtype not in DTYPES or not all(isinstance(a, str) or (isinstance(a, int) and a >= 0) for a in shape):
            raise BundleError(f"{where}.{name}: dtype must be one of {DTYPES} and shape a list of sizes/axis names")
        out[name] = (dtype, tuple(shape))
    return out


def parse_manifest(meta: dict, path: Path) -> Bundle:
    """A :class:`Bundle` from a parsed model.json (structure checked, files not yet)."""
    where = str(path / MANIFEST)
    fmt = _get(meta, "format", int, where)
    if fmt > BUNDLE_FORMAT:
        raise BundleError(f"{where}: bundle format {fmt} is newer than this software reads "
                          f"({BUNDLE_FORMAT}); upgrade adaptive-ocnn or re-export the model")
    if fmt < 1:
        raise BundleError(f"{where}: bundle format must be >= 1, got {fmt}")
    task = _get(meta, "task", str, where)
    if task not in TASKS:
        raise BundleError(f"{where}: unknown task {task!r}; expected one of {', '.join(TASKS)}")
    o = _get(meta, "octree", dict, where)
    ow = f"{where}: octree"
    classes = {int(k): v for k, v in _get(o, "classes", dict, ow).items()}
    threshold = o.get("threshold")
    octree = OctreeSpec(depth=_get(o, "depth", int, ow), full_depth=_get(o, "full_depth", int, ow),
                        adaptive_depth=_get(o, "adaptive_depth", int, ow), adaptive=_get(o, "adaptive", bool, ow),
                        classes=classes, planes=tuple(_get(o, "planes", list, ow)), latent=_get(o, "latent", int, ow),
                        threshold=None if threshold is None else float(threshold), signal=o.get("signal", "all"),
                        guided=o.get("guided", False))
    if not 0 <= octree.full_depth <= octree.adaptive_depth <= octree.depth <= MAX_BUILD_DEPTH:
        raise BundleError(f"{ow}: need 0 <= full_depth <= adaptive_depth <= depth <= {MAX_BUILD_DEPTH}")
    if threshold is not None and not (isinstance(threshold, (int, float)) and math.isfinite(threshold) and threshold > 0):
        raise BundleError(f"{ow}: threshold must be a positive number")
    graphs = {}
    for name, g in _get(meta, "graphs", dict, where).items():
        gw = f"{where}: graphs.{name}"
        file = _get(g, "file", str, gw)
        if Path(file).name != file or not file.endswith(".onnx"):
            raise BundleError(f"{gw}: file must be a plain .onnx file name inside the bundle, got {file!r}")
        graphs[name] = GraphSpec(name, file, _get(g, "sha256", str, gw), _io(g.get("inputs"), f"{gw}.inputs"),
                                 _io(g.get("outputs"), f"{gw}.outputs"))
    output = _get(meta, "output", dict, where)
    try:
        keep_scan_bias = empty_bias_of(output.get("keep_scan"))
    except ValueError:
        keep_scan_bias = None
    if keep_scan_bias is None or any(d > octree.depth for d in keep_scan_bias):
        raise BundleError(f"{where}: output.keep_scan.empty_bias must map depths (<= {octree.depth}) to numbers")
    missing = [g for g in required_graphs(task, octree) if g not in graphs]
    if missing:
        raise BundleError(f"{where}: a {task} bundle needs the graphs {', '.join(missing)}")
    if not isinstance(octree.guided, bool):
        raise BundleError(f"{ow}: guided must be true or false")
    if octree.guided:
        _check_guided(graphs, octree, where)
    return Bundle(path=path, format=fmt, task=task, name=_get(meta, "name", str, where),
                  version=_get(meta, "version", str, where), octree=octree,
                  input=_get(meta, "input", dict, where), output=output,
                  categories=list(meta.get("categories") or []), graphs=graphs, meta=meta,
                  keep_scan_bias=keep_scan_bias)


def _check_guided(graphs: dict[str, GraphSpec], octree: OctreeSpec, where: str) -> None:
    """A guided bundle's graphs pass the skip features: the octree encoder outputs ``skip_d`` for
    every decoded depth d and each ``decoder_predict_d`` reads ``skip`` and ``skip_index``."""
    depths = range(octree.full_depth, octree.depth + 1)
    encoder = graphs.get("octree_encoder")
    if encoder is None or any(f"skip_{d}" not in encoder.outputs for d in depths):
        raise BundleError(f"{where}: a guided bundle's octree_encoder must output skip_{octree.full_depth}"
                          f"..skip_{octree.depth}")
    for d in depths:
        if not {"skip", "skip_index"} <= set(graphs[f"decoder_predict_{d}"].inputs):
            raise BundleError(f"{where}: a guided bundle's decoder_predict_{d} must read skip and skip_index")


def load_bundle(path: str | Path) -> Bundle:
    """Read and verify a bundle folder: manifest structure, every graph file present, checksums.

    Raises :class:`BundleError` naming the file and the problem (missing, tampered, too new,
    incomplete).  The graphs' inputs are checked against the spec when sessions are created
    (:class:`export.runtime.Runtime`).
    """
    path = Path(path)
    manifest = path / MANIFEST
    if not path.is_dir():
        raise BundleError(f"{path}: not a bundle folder (no such directory)")
    if not manifest.is_file():
        raise BundleError(f"{manifest}: missing; a bundle folder holds model.json and its .onnx files")
    try:
        meta = json.loads(manifest.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise BundleError(f"{manifest}: not valid JSON ({exc})") from None
    bundle = parse_manifest(meta, path)
    for g in bundle.graphs.values():
        f = path / g.file
        if not f.is_file():
            raise BundleError(f"{f}: missing (listed in model.json as graph {g.name})")
        digest = sha256_file(f)
        if digest != g.sha256:
            raise BundleError(f"{f}: sha256 {digest} does not match model.json ({g.sha256}): "
                              f"the file is corrupt or was modified; re-export the bundle")
    return bundle
