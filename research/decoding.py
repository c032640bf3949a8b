"""Decoding for evaluation: every decoder's output as points in the unit cube (octree decoders
through the shared decode loop, in torch or onnxruntime; point sets; AtlasNet's patch grids), the
diagnostic oracles, and the teacher-forced status confusion."""

from __future__ import annotations

import numpy as np
import torch

from model.decode import Guide, decode
from model.networks import AtlasNetDecoder, PointSetDecoder, TorchSteps
from model.networks.decoder import teacher_skips
from model.nn.tensors import OctreeTensors
from model.octree import LEAF, Octree
from model.octree.batch import split_octree
from model.octree.fuse import keep_scan
from model.octree.metrics import sample_patches

ORACLES = ("none", "structure", "all")


class Oracle:
    """Decoder steps whose statuses (and with ``planes``, planes) are the ground truth's:
    separates the Chamfer lost to wrong structure, to wrong patches, and to the representation."""

    def __init__(self, steps: TorchSteps, truth: Octree, planes: bool = False):
        self.steps, self.truth, self.depth, self.planes = steps, truth, steps.depth, planes

    def classes(self, depth: int) -> int:
        return self.steps.classes(depth)

    def start(self, latent):
        return self.steps.start(latent)

    def predict(self, depth: int, x, neighbors: np.ndarray, *skip):
        x, logits, plane = self.steps.predict(depth, x, neighbors, *skip)
        label = torch.from_numpy(self.truth.levels[depth].label)
        status = self.steps.decoder.status_targets(depth, label).numpy()
        if self.planes and plane is not None:
            plane = self.truth.levels[depth].plane
        return x, np.eye(self.classes(depth), dtype=np.float32)[status], plane

    def expand(self, depth: int, x, split: np.ndarray):
        return self.steps.expand(depth, x, split)


def status_confusion(model, latent: torch.Tensor, octree: Octree, guide: Guide | None = None
                     ) -> dict[int, np.ndarray]:
    """Per depth, the confusion matrix (truth x predicted status) of predictions teacher-forced
    over ``octree`` (a guided decoder with its input's ``guide``)."""
    dec = model.decoder
    tensors = OctreeTensors.from_octree(octree)
    with torch.no_grad():
        outputs = dec(latent, tensors, teacher_skips(guide, octree))
    out = {}
    for (logits, _), d in zip(outputs, range(dec.full_depth, dec.depth + 1)):
        k = dec.classes(d)
        truth = dec.status_targets(d, tensors.levels[d].label).numpy()
        pred = logits.argmax(1).numpy()
        out[d] = np.bincount(truth * k + pred, minlength=k * k).reshape(k, k)
    return out


ATLAS_GRID = 20
"""AtlasNet evaluation: a 20 x 20 uv grid per patch (10,000 points for 25 patches)."""


def decoded_points(model, latent: torch.Tensor, octree_batch: Octree | None, resolution: int, seed: int,
                   oracle: str = "none", steps=None, scans: list[Octree] | None = None,
                   empty_bias: dict[int, float] | None = None, guide: Guide | None = None
                   ) -> list[tuple[np.ndarray, Octree | None]]:
    """Per shape of the batch: decoded points in cube coordinates, and the decoded octree (or None).
    ``steps``: the decoder steps to grow octrees with (default: the torch decoder's).  ``scans``:
    each shape's input scan octree, kept where it saw the shape (:func:`keep_scan`); ``empty_bias``
    and ``guide`` (a guided decoder's input) as :func:`model.decode.decode`'s."""
    dec = model.decoder
    if isinstance(dec, (PointSetDecoder, AtlasNetDecoder)):
        with torch.no_grad():
            pts = (dec.grid(latent, ATLAS_GRID) if isinstance(dec, AtlasNetDecoder) else dec(latent)).numpy()
        return [(p.astype(np.float64), None) for p in pts]
    steps = steps or TorchSteps(dec)
    out = []
    if oracle != "none":
        steps = Oracle(steps, octree_batch, planes=oracle == "all")
    for b, tree in enumerate(split_octree(decode(steps, latent.numpy(), empty_bias=empty_bias, guide=guide), neighbors=False)):
        if scans is not None:
            tree = keep_scan(tree, scans[b])
        if dec.has_plane(tree.depth):
            pts = sample_patches(tree, resolution=resolution, seed=seed, world=False)
        else:
            lv = tree.levels[-1]
            pts = lv.centers()[lv.label == LEAF]
        out.append((pts, tree))
    return out
