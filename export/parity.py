"""Two implementations of one model compared step by step, with tolerances that hold on every CPU.

onnxruntime and torch pick different kernels on different instruction sets (AVX2, AVX-512, VNNI),
so their float32 results differ in the last bits, and a decode that takes a near-tied status
logit one way on one machine may take it the other way on the next: whole decodes are not
comparable bit for bit.  The comparison is therefore made in *lockstep* (:class:`Lockstep`): the
reference implementation's decode decides the octree, and at every step both implementations
run on the same octants (the same parents, neighbour tables and split octants), each on its own
features; every output (features, status logits, planes) is compared within a relative
tolerance.  Which way a near-tie went is reported as a statistic (:attr:`ParityReport.label_agreement`),
never a pass/fail threshold.

No torch here: the reference is any :class:`model.decode.DecoderSteps` (the exporter passes
torch's, the tests may pass a perturbed runtime's).
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from model.decode import DecoderSteps, Guide, decode, status_to_labels
from model.octree import EMPTY, LEAF, Octree, build_octree, validate
from model.octree import keys as morton
from model.octree.batch import merge_octrees

RELATIVE_TOLERANCE = 1e-4
"""The largest difference allowed between two implementations' float32 outputs, relative to the
reference output's largest magnitude (at least 1).  Kernels of different instruction sets differ
by about 1e-6 of it; a wrong weight, a transposed plane or a gather off by one differ by 1e-2 to 1."""


def as_array(x: Any) -> np.ndarray:
    """NumPy view of an output of either implementation (a NumPy array or a torch tensor)."""
    if hasattr(x, "detach"):
        x = x.detach().cpu().numpy()
    return np.asarray(x)


def relative_error(reference: Any, other: Any) -> float:
    """max |reference - other| / max(1, max |reference|); inf when the shapes differ or a value is
    not finite."""
    a, b = as_array(reference).astype(np.float64), as_array(other).astype(np.float64)
    if a.shape != b.shape:
        return float("inf")
    if a.size == 0:
        return 0.0
    if not (np.isfinite(a).all() and np.isfinite(b).all()):
        return float("inf")
    return float(np.abs(a - b).max() / max(1.0, float(np.abs(a).max())))


@dataclasses.dataclass(frozen=True)
class StepDiff:
    """One compared output: ``name`` (graph/output, e.g. ``decoder_predict_5/planes``), its
    relative error (:func:`relative_error`) and its row count."""

    name: str
    error: float
    rows: int


@dataclasses.dataclass
class ParityReport:
    """Every output compared between a reference and another implementation.

    ``label_agreement``: the share of octants whose status (argmax of the logits) both
    implementations chose alike, in lockstep; ``decode_label_agreement``: the same for two
    independent whole decodes (the octants of the reference's octree the other also grew, with
    the same label).  Both are statistics: a near-tie may go either way on another CPU."""

    tolerance: float = RELATIVE_TOLERANCE
    steps: list[StepDiff] = dataclasses.field(default_factory=list)
    same_status: int = 0
    nodes: int = 0
    decode_label_agreement: float | None = None

    def compare(self, name: str, reference: Any, other: Any) -> float:
        """Record one output's relative error; returns it."""
        error = relative_error(reference, other)
        self.steps.append(StepDiff(name, error, int(as_array(reference).shape[0]) if as_array(reference).ndim else 1))
        return error

    def count_status(self, reference_logits: Any, other_logits: Any) -> None:
        a, b = as_array(reference_logits), as_array(other_logits)
        if a.shape == b.shape and a.size:
            self.same_status += int(np.sum(a.argmax(1) == b.argmax(1)))
            self.nodes += len(a)

    @property
    def label_agreement(self) -> float:
        return self.same_status / self.nodes if self.nodes else 1.0

    @property
    def worst(self) -> StepDiff | None:
        return max(self.steps, key=lambda s: s.error, default=None)

    @property
    def failures(self) -> list[StepDiff]:
        return [s for s in self.steps if not s.error <= self.tolerance]

    @property
    def ok(self) -> bool:
        return bool(self.steps) and not self.failures

    def summary(self) -> str:
        """One line: the first failure (or the worst step) and the statistics."""
        bad = self.failures
        step = bad[0] if bad else self.worst
        head = (f"{step.name} differs by {step.error:.2e} of its magnitude (tolerance {self.tolerance:.0e})"
                if bad else f"{len(self.steps)} outputs within {step.error:.1e} of their magnitude" if step
                else "nothing compared")
        stats = f"statuses {self.label_agreement:.4%} alike over {self.nodes} octants in lockstep"
        if self.decode_label_agreement is not None:
            stats += f", {self.decode_label_agreement:.4%} in whole decodes"
        return f"{head}; {stats}"

    def to_dict(self) -> dict:
        worst = self.worst
        out = {"outputs_compared": len(self.steps), "relative_tolerance": self.tolerance,
               "max_relative_error": worst.error if worst else 0.0, "worst_output": worst.name if worst else None,
               "lockstep_label_agreement": self.label_agreement, "nodes": self.nodes}
        if self.decode_label_agreement is not None:
            out["decode_label_agreement"] = self.decode_label_agreement
        return out


class Lockstep:
    """:class:`model.decode.DecoderSteps` over two implementations, each step isolated: the
    reference's outputs drive the decode (its status logits decide the octree, its features are
    carried on), the other runs every step on the reference's inputs (the same features, octants,
    neighbour tables, split octants and skip features, as NumPy arrays), and every output pair is
    compared in ``report``.  A step's error is then that step's own (kernels of another instruction
    set: about 1e-6 of the outputs' magnitude), not one amplified through the levels before it,
    and a defect shows at the step that has it."""

    def __init__(self, reference: DecoderSteps, other: DecoderSteps, report: ParityReport):
        self.reference, self.other, self.report = reference, other, report
        self.depth = reference.depth

    def classes(self, depth: int) -> int:
        return self.reference.classes(depth)

    def start(self, latent: np.ndarray) -> Any:
        x = self.reference.start(latent)
        self.report.compare("decoder_start/features", x, self.other.start(latent))
        return x

    def predict(self, depth: int, features: Any, neighbors: np.ndarray, skip: Any = None,
                skip_index: np.ndarray | None = None):
        skips = () if skip is None else (skip, skip_index)
        theirs = () if skip is None else (as_array(skip), skip_index)
        x, logits, planes = self.reference.predict(depth, features, neighbors, *skips)
        x_o, logits_o, planes_o = self.other.predict(depth, as_array(features), neighbors, *theirs)
        name = f"decoder_predict_{depth}"
        self.report.compare(f"{name}/features", x, x_o)
        self.report.compare(f"{name}/logits", logits, logits_o)
        if (planes is None) != (planes_o is None):
            self.report.steps.append(StepDiff(f"{name}/planes", float("inf"), 0))
        elif planes is not None:     # the patches the decode keeps (an empty octant's plane is dropped,
            # and its normal, normalised from a vector near zero, is as unstable as it is unused)
            filled = status_to_labels(as_array(logits), self.classes(depth), depth == self.depth) != EMPTY
            self.report.compare(f"{name}/planes", as_array(planes)[filled], as_array(planes_o)[filled])
        self.report.count_status(logits, logits_o)
        return x, logits, planes

    def expand(self, depth: int, features: Any, split: np.ndarray) -> Any:
        x = self.reference.expand(depth, features, split)
        self.report.compare(f"decoder_expand_{depth}/features", x, self.other.expand(depth, as_array(features), split))
        return x


def decoder_parity(reference: DecoderSteps, other: DecoderSteps, latent: np.ndarray, full_depth: int,
                   adaptive_depth: int, report: ParityReport | None = None, other_latent: np.ndarray | None = None,
                   guides: tuple[Guide, Guide] | None = None) -> tuple[ParityReport, Octree]:
    """Decode ``latent`` with both implementations in lockstep (:class:`Lockstep`, with the
    reference's guide), then the other alone, from its own encoding of the same input
    (``other_latent`` and the second guide; default: the reference's), for the whole-decode
    statistic.  Returns the report and the reference's octree."""
    report = report or ParityReport()
    tree = decode(Lockstep(reference, other, report), latent, full_depth, adaptive_depth,
                  guide=None if guides is None else guides[0])
    own = latent if other_latent is None else other_latent
    alone = decode(other, own, full_depth, adaptive_depth, guide=None if guides is None else guides[1])
    report.decode_label_agreement = label_agreement(tree, alone)
    return report, tree


def probe_octrees(depth: int, batch: int = 3, seed: int = 0, adaptive: bool = True) -> Octree:
    """``batch`` merged octrees (with neighbour tables) of random ellipsoids' half surfaces, as a
    scanner sees them: inputs for checking graphs that read octrees (``adaptive`` False: full
    octrees, as the O-CNN baselines read)."""
    rng = np.random.default_rng(seed)
    trees = []
    for _ in range(batch):
        n = rng.normal(size=(4000, 3))
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        n = n[n[:, 2] > -0.2]                                  # the side a scanner saw
        axes = rng.uniform(0.5, 1.0, 3)
        trees.append(build_octree(validate(n * axes, n / axes), depth, adaptive=adaptive, neighbors=False))
    return merge_octrees(trees, neighbors=True)


def label_agreement(reference: Octree, other: Octree) -> float:
    """The share of ``reference``'s octants (every depth) that ``other`` grew too with the same label."""
    same = total = 0
    for a, b in zip(reference.levels, other.levels):
        total += len(a)
        rows = morton.lookup(b.key, a.key)
        found = rows < len(b)
        same += int(np.sum(b.label[rows[found]] == a.label[found]))
    return same / total if total else 1.0


def leaf_planes(octree: Octree) -> dict[tuple[int, int], np.ndarray]:
    """(depth, key) -> plane of every leaf of a (batched) octree."""
    return {(lv.depth, int(k)): p for lv in octree.levels
            for k, p in zip(lv.key[lv.label == LEAF], lv.plane[lv.label == LEAF].astype(np.float64))}
