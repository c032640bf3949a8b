"""Training tasks as plug-ins of the one training loop: what a task reads, builds and feeds.

A task gives the loop its datasets, its model (whose ``forward`` returns the loss dictionary) and
the model inputs of a batch; the loop (:mod:`model.train.loop`) does the rest.  Evaluation asks
the same task for the latent codes of a batch.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import json
import shutil
from pathlib import Path
from typing import Protocol

import numpy as np
import torch
from torch import nn

from ..decode import Guide, matched_rows
from ..files import atomic_path
from ..image.frame import ImageSpec, prepare_image
from ..image.mask import MaskSpec
from ..networks import ARCHS, IMAGE_DECODERS, IMAGE_ENCODERS, Autoencoder, ImageToShape
from ..networks.classifier import CLASSIFIER_ARCHS, Classifier
from ..networks.decoder import STRUCTURE_LOSSES
from ..networks.foreground import FOREGROUND_ARCHS, ForegroundModel, torch_segment
from ..nn.tensors import OctreeTensors
from ..octree.geometry import ROTATIONS
from .classify import ClassifySet
from .completion import CompletionSet
from .config import TrainConfig, read_run
from .data import RecordSet, manifest_rows
from .foreground import mask_batch, refine_batch, thin_parts, tubed_skeletons
from .images import eval_view, image_batch


class Task(Protocol):
    name: str

    def check(self, cfg: TrainConfig) -> None:
        """Raise ValueError naming the first setting this task cannot train with."""

    def dataset(self, cfg: TrainConfig, split: str, seed: int, points: int = 2048,
                limit: int | None = None) -> RecordSet: ...

    def build_model(self, cfg: TrainConfig) -> nn.Module: ...

    def inputs(self, cfg: TrainConfig, dataset: RecordSet, indices, rng: np.random.Generator | None) -> tuple:
        """The model's forward arguments for a batch (random augmentation with ``rng``)."""

    def encode(self, model: nn.Module, cfg: TrainConfig, dataset: RecordSet, indices) -> torch.Tensor:
        """Latent codes of shapes ``indices`` without augmentation (evaluation)."""


def _check_structure(cfg: TrainConfig) -> None:
    if cfg.structure_loss not in STRUCTURE_LOSSES:
        raise ValueError(f"--structure-loss must be one of {', '.join(STRUCTURE_LOSSES)}")


class OctreeInputTask:
    """A task whose model's first input is an octree and whose encoder reads it."""

    def encode(self, model, cfg, dataset, indices):
        return model.encoder(self.inputs(cfg, dataset, indices, None)[0])


class AutoencoderTask(OctreeInputTask):
    """Paper section 5.2: an octree in, the same shape out (``cfg.arch`` of :data:`ARCHS`)."""

    name = "autoencoder"

    def check(self, cfg: TrainConfig) -> None:
        if cfg.arch not in ARCHS:
            raise ValueError(f"unknown arch {cfg.arch!r}; choose from {', '.join(sorted(ARCHS))}")
        _check_structure(cfg)

    def dataset(self, cfg, split, seed, points=2048, limit=None):
        return RecordSet(cfg.data, split, ARCHS[cfg.arch].octree, points=points, depth=cfg.depth,
                         limit=limit, seed=seed, categories=cfg.categories, workers=cfg.workers,
                         stream=cfg.stream)

    def build_model(self, cfg):
        return Autoencoder(cfg.arch, cfg.depth, latent=cfg.latent, base_channels=cfg.channels,
                           hidden=cfg.pred_hidden, structure_loss=cfg.structure_loss,
                           decoder_blocks=cfg.decoder_blocks, guided=cfg.skips)

    def inputs(self, cfg, dataset, indices, rng):
        octree, points = dataset.batch(indices)
        return OctreeTensors.from_octree(octree), torch.from_numpy(points)


class ImageTask:
    """Paper section 5.3: a render in, the shape out (``cfg.encoder`` + ``cfg.arch`` as decoder).

    With ``cfg.teacher`` the encoder is regressed onto a teacher's latent codes and the teacher's
    decoder is used: an autoencoder's code of each shape, or an image model's code of each view on
    the plain background (the student starts from the teacher's weights and learns to give photos
    the code the teacher gives the clean render)."""

    name = "image"

    def check(self, cfg: TrainConfig) -> None:
        if cfg.arch not in IMAGE_DECODERS:
            raise ValueError(f"unknown decoder {cfg.arch!r}; choose from {', '.join(IMAGE_DECODERS)}")
        if cfg.encoder not in IMAGE_ENCODERS:
            raise ValueError(f"unknown encoder {cfg.encoder!r}; choose from {', '.join(IMAGE_ENCODERS)}")
        if not 32 <= cfg.image_size <= 512:
            raise ValueError(f"--image-size must be in 32..512, got {cfg.image_size}")
        if not 0 <= cfg.background_share <= 1:
            raise ValueError(f"--background-share must be in [0, 1], got {cfg.background_share}")
        if not 0 <= cfg.photo_share <= 1:
            raise ValueError(f"--photo-share must be in [0, 1], got {cfg.photo_share}")
        if cfg.foreground_ratio is not None and not 0.3 <= cfg.foreground_ratio <= 1:
            raise ValueError(f"--foreground-ratio must be in 0.3..1, got {cfg.foreground_ratio}")
        if cfg.teacher is not None:
            teacher = self._teacher(cfg)[1]
            if cfg.arch != "aocnn" or teacher.arch != "aocnn":
                raise ValueError("--teacher needs --decoder aocnn and an aocnn autoencoder or image run")
            keys = ["depth", "latent", "channels", "pred_hidden", "decoder_blocks"]
            if teacher.task == "image":
                keys += ["encoder", "encoder_width", "image_size"]
            for key in keys:
                if getattr(teacher, key) != getattr(cfg, key):
                    raise ValueError(f"--teacher was trained with {key}={getattr(teacher, key)!r}, "
                                     f"not {getattr(cfg, key)!r}: pass the same setting")
        _check_structure(cfg)

    @staticmethod
    def _teacher(cfg):
        return _load_teacher(str(cfg.teacher))

    def spec(self, cfg) -> ImageSpec:
        return cfg.image_spec()

    def dataset(self, cfg, split, seed, points=2048, limit=None):
        data = RecordSet(cfg.data, split, "adaptive", points=points, depth=cfg.depth, limit=limit,
                         seed=seed, images=True, categories=cfg.categories, workers=cfg.workers,
                         stream=cfg.stream)
        if cfg.teacher is not None:
            data.latents = self._teacher_codes(cfg, data, split)
        return data

    def _teacher_codes(self, cfg: TrainConfig, data: RecordSet, split: str) -> torch.Tensor:
        """The teacher's codes of every shape of ``data`` (an image teacher: of every view), computed
        once per run and split and kept in ``RUN/teacher-codes/`` under a key of the teacher's
        weights, the records' checksums and the image spec, so a resumed run reads them back
        (at depth 7 an image teacher's codes of 8,342 shapes' 24 views take half an hour on 2 cores).
        They are saved in parts of ``TEACHER_CODES_PART`` shapes as they are made
        (``<split>-<key>/<first shape>.pt``), so an interrupted computation goes on from its last part;
        the parts are joined into ``<split>-<key>.pt`` at the end."""
        model, tcfg = self._teacher(cfg)
        spec = tcfg.image_spec() if tcfg.task == "image" else None
        digest = hashlib.sha256(json.dumps([tcfg.task, repr(spec), data.record_sha256]).encode())
        for name, tensor in sorted(model.state_dict().items()):
            digest.update(name.encode())
            digest.update(tensor.detach().cpu().contiguous().numpy().tobytes())
        path = Path(cfg.out) / "teacher-codes" / f"{split}-{digest.hexdigest()[:16]}.pt"
        if path.is_file():
            return torch.load(path)
        parts = path.with_suffix("")
        parts.mkdir(parents=True, exist_ok=True)
        codes = []
        for start in range(0, len(data), TEACHER_CODES_PART):
            part = parts / f"{start:06d}.pt"
            if part.is_file():
                codes.append(torch.load(part))
                continue
            codes.append(_codes_of(model, spec, data, start, min(len(data), start + TEACHER_CODES_PART)))
            with atomic_path(part) as tmp:
                torch.save(codes[-1], tmp)
        latents = torch.cat(codes)
        with atomic_path(path) as tmp:
            torch.save(latents, tmp)
        shutil.rmtree(parts)
        return latents

    def build_model(self, cfg):
        model = _image_to_shape(cfg)
        if cfg.teacher is not None:
            teacher, tcfg = self._teacher(cfg)
            if tcfg.task == "image":
                model.load_state_dict(teacher.state_dict())
            else:
                model.adopt_decoder(teacher.decoder)
        return model

    def inputs(self, cfg, dataset, indices, rng):
        samples = [dataset.samples[i] for i in indices]
        views = None
        if rng is not None:
            views = np.array([rng.integers(len(s.images)) for s in samples])
        images = image_batch(samples, self.spec(cfg), rng, cfg.background_share, dataset.samples, views,
                             cfg.photo_share)
        if cfg.teacher is not None:
            idx = torch.as_tensor(np.asarray(indices))
            latents = dataset.latents[idx]
            if latents.ndim == 3:             # an image teacher: the code of the view shown
                if views is None:
                    views = np.array([eval_view(s.shape_id, len(s.images)) for s in samples])
                latents = latents[torch.arange(len(idx)), torch.as_tensor(views)]
            return torch.from_numpy(images), None, None, latents
        if cfg.arch == "aocnn":
            octree, points = dataset.batch(indices)
            octree_t = OctreeTensors.from_octree(octree)
        else:               # point decoders need no octree
            octree_t, points = None, np.stack([s.points for s in samples])
        return torch.from_numpy(images), octree_t, torch.from_numpy(points)

    def encode(self, model, cfg, dataset, indices):
        samples = [dataset.samples[i] for i in indices]
        return model.encoder(torch.from_numpy(image_batch(samples, self.spec(cfg), None)))


COMPLETION_ARCHS = ("aocnn", "ocnn-patch", "ocnn-patch-star", "ocnn-binary")
"""Completion networks: the Adaptive O-CNN encoder-decoder and the O-CNN full-octree baselines."""


class CompletionTask(AutoencoderTask):
    """Paper section 5.2, shape completion: a partial scan's octree in, the complete shape's out,
    both in the scan's frame (``cfg.arch`` of :data:`COMPLETION_ARCHS`, trained end to end; the
    autoencoders' networks)."""

    name = "completion"

    def check(self, cfg: TrainConfig) -> None:
        if cfg.arch not in COMPLETION_ARCHS:
            raise ValueError(f"unknown arch {cfg.arch!r}; choose from {', '.join(COMPLETION_ARCHS)}")
        _check_structure(cfg)

    def dataset(self, cfg, split, seed, points=2048, limit=None, normals: str = "given",
                symmetry: float | None = None):
        return CompletionSet(cfg.data, split, ARCHS[cfg.arch].octree, points=points, depth=cfg.depth,
                             limit=limit, seed=seed, categories=cfg.categories, normals=normals,
                             workers=cfg.workers, stream=cfg.stream, symmetry=symmetry)

    def inputs(self, cfg, dataset, indices, rng):
        source, target = dataset.pairs(indices, rng)
        rows = {d: torch.from_numpy(r) for d, r in matched_rows(source, target).items()} if cfg.skips else None
        return OctreeTensors.from_octree(source), None, OctreeTensors.from_octree(target), rows


class ClassifyTask(OctreeInputTask):
    """Paper section 5.1: an octree in, its category out (``cfg.arch``: aocnn or ocnn), trained
    with each shape at 12 rotations about the up axis (one drawn per step)."""

    name = "classify"

    def check(self, cfg: TrainConfig) -> None:
        if cfg.arch not in CLASSIFIER_ARCHS:
            raise ValueError(f"unknown arch {cfg.arch!r}; choose from {', '.join(CLASSIFIER_ARCHS)}")
        if cfg.stream:
            raise ValueError("classification holds its split in memory: stream must be 0")
        if not cfg.categories:         # the classes: every category of the dataset, fixed in the config
            manifest, _ = manifest_rows(Path(cfg.data), "train", cfg.depth)
            cfg.categories = sorted({r["category"] for r in manifest["records"]})
        if len(cfg.categories) < 2:
            raise ValueError("classification needs at least 2 categories")

    def dataset(self, cfg, split, seed, points=2048, limit=None):
        return ClassifySet(cfg.data, split, cfg.categories, CLASSIFIER_ARCHS[cfg.arch][0], depth=cfg.depth,
                           limit=limit, up=cfg.up, workers=cfg.workers)

    def build_model(self, cfg):
        return Classifier(cfg.arch, cfg.depth, len(cfg.categories), latent=cfg.latent, base_channels=cfg.channels)

    def inputs(self, cfg, dataset, indices, rng):
        rotation = 0 if rng is None else rng.integers(ROTATIONS, size=len(indices))
        octree, labels = dataset.batch(indices, rotation)
        return OctreeTensors.from_octree(octree), torch.from_numpy(labels)


def _image_to_shape(cfg: TrainConfig) -> ImageToShape:
    """The image task's network, untrained, as ``cfg`` describes it (no teacher involved)."""
    return ImageToShape(cfg.encoder, cfg.arch, cfg.depth, latent=cfg.latent, base_channels=cfg.channels,
                        encoder_width=cfg.encoder_width, hidden=cfg.pred_hidden,
                        structure_loss=cfg.structure_loss, decoder_blocks=cfg.decoder_blocks)


TEACHER_CODES_PART = 512        # shapes per saved part of a split's teacher codes


def _codes_of(model: nn.Module, spec: ImageSpec | None, data: RecordSet, start: int, stop: int) -> torch.Tensor:
    """The teacher's codes of shapes ``start``..``stop - 1`` of ``data``: an image teacher's of every
    view (shapes x views x latent), an autoencoder's of each shape's octree, 16 shapes at a time."""
    codes = []
    with torch.no_grad():
        if spec is not None:
            for s in (data.samples[i] for i in range(start, stop)):
                views = np.stack([prepare_image(v, spec) for v in s.images])
                codes.append(model.encoder(torch.from_numpy(views))[None])
        else:
            for s in range(start, stop, 16):
                octree, _ = data.batch(np.arange(s, min(stop, s + 16)))
                codes.append(model.encoder(OctreeTensors.from_octree(octree)))
    return torch.cat(codes)


@functools.lru_cache(maxsize=4)
def _load_teacher(run: str) -> tuple[nn.Module, TrainConfig]:
    """A teacher run (model in eval mode, config), loaded once per process: an autoencoder, or an
    image model (built from its weights alone: its own teacher is not needed)."""
    saved = read_run(run)
    task = saved.config.task
    if task not in ("autoencoder", "image"):
        raise ValueError(f"--teacher {run} is a {task} run, not an autoencoder or image model")
    model = _image_to_shape(saved.config) if task == "image" else AutoencoderTask().build_model(saved.config)
    model.load_state_dict(saved.weights)
    return model.eval(), saved.config


class ForegroundTask:
    """Background removal for photos: a render composited into a photo in, its exact mask out
    (``cfg.image_size``: the network's input side; ``cfg.encoder_width``: the U-Net's width)."""

    name = "foreground"

    def check(self, cfg: TrainConfig) -> None:
        if cfg.arch not in FOREGROUND_ARCHS:
            raise ValueError(f"unknown foreground network {cfg.arch!r}; choose from {', '.join(FOREGROUND_ARCHS)}")
        step = FOREGROUND_ARCHS[cfg.arch].divisor
        if cfg.image_size % step or not 32 <= cfg.image_size <= 512:
            raise ValueError(f"--image-size must be a multiple of {step} in 32..512 for {cfg.arch}, got {cfg.image_size}")
        if not 0 <= cfg.crop_share <= 1:
            raise ValueError(f"--crop-share must be in 0..1, got {cfg.crop_share}")
        if not cfg.skeleton_weight >= 0:
            raise ValueError(f"--skeleton-weight must be 0 or more, got {cfg.skeleton_weight}")

    def spec(self, cfg, meta: dict | None = None) -> MaskSpec:
        """How the network takes images: a network trained on second looks' views (``crop_share``)
        looks again at small squares too (:data:`TRAINED_REFINE_MIN`); the guided filter of its
        masks is the one calibrated for it (``meta``'s ``mask_guide``: a run's or checkpoint's
        provenance), else none."""
        guide = (meta or {}).get("mask_guide") or {}
        return MaskSpec(size=cfg.image_size, refine_min=TRAINED_REFINE_MIN if cfg.crop_share > 0 else None,
                        guide=float(guide.get("radius", 0.0)), guide_eps=float(guide.get("eps", MaskSpec.guide_eps)))

    def dataset(self, cfg, split, seed, points=2048, limit=None):
        # renders only: a dataset of any octree depth serves (the same shapes, the same renders)
        return RecordSet(cfg.data, split, None, depth=None, limit=limit, seed=seed,
                         images=True, categories=cfg.categories, workers=cfg.workers, stream=cfg.stream)

    def build_model(self, cfg):
        return ForegroundModel(cfg.encoder_width or FOREGROUND_WIDTH, skeleton_weight=cfg.skeleton_weight,
                               arch=cfg.arch)

    def inputs(self, cfg, dataset, indices, rng):
        images, masks = mask_batch([dataset.samples[i] for i in indices], self.spec(cfg), rng, cfg.crop_share)
        if cfg.skeleton_weight > 0:
            return torch.from_numpy(images), torch.from_numpy(masks), torch.from_numpy(tubed_skeletons(masks))
        return torch.from_numpy(images), torch.from_numpy(masks)

    def encode(self, model, cfg, dataset, indices):
        raise ValueError("the foreground network has no latent code")


class RefineTask(ForegroundTask):
    """The foreground refinement network (a second look at the object's resolution): the object's
    square of a photo, with the first network's mask as a fourth channel, in; the exact mask over
    the square out (``cfg.image_size``: the square's side in the network, ``cfg.teacher``: the
    first network, a foreground run or checkpoint, whose served mask is the input)."""

    name = "refine"

    def check(self, cfg: TrainConfig) -> None:
        super().check(cfg)
        if cfg.teacher is None:
            raise ValueError("--teacher must name the first foreground network (a foreground run or checkpoint)")
        _first_stage(cfg.teacher)                  # a foreground network, or ValueError

    def spec(self, cfg, meta: dict | None = None) -> MaskSpec:
        """The refinement's settings: its input side, the first network's mask settings."""
        first = _first_stage(cfg.teacher)[1]
        return dataclasses.replace(first, crop_size=cfg.image_size)

    def build_model(self, cfg):
        return ForegroundModel(cfg.encoder_width or FOREGROUND_WIDTH, skeleton_weight=cfg.skeleton_weight,
                               arch=cfg.arch, in_channels=4)

    def inputs(self, cfg, dataset, indices, rng):
        net, first = _first_stage(cfg.teacher)
        images, masks = refine_batch([dataset.samples[i] for i in indices], torch_segment(net, first), first,
                                     self.spec(cfg), rng)
        out = [torch.from_numpy(images), torch.from_numpy(masks)]
        out.append(torch.from_numpy(tubed_skeletons(masks)) if cfg.skeleton_weight > 0 else None)
        return (*out, torch.from_numpy(thin_parts(masks)))


@functools.lru_cache(maxsize=2)
def _first_stage(path: str) -> tuple[nn.Module, MaskSpec]:
    """The first foreground network of a refinement (eval mode) and its served mask settings."""
    saved = read_run(path)
    if saved.config.task != "foreground":
        raise ValueError(f"--teacher {path} is a {saved.config.task} run, not a foreground network")
    model = ForegroundTask().build_model(saved.config)
    model.load_state_dict(saved.weights)
    return model.net.eval(), ForegroundTask().spec(saved.config, saved.meta)


TRAINED_REFINE_MIN = 32
"""The smallest square a network trained on second looks' views looks at again: every small object
of the photo-like views (a network fine-tuned so scored 0.857 on validation with every second look,
0.858 with squares of 96 px or more, 0.855 with the untrained network's 128: docs/journal/2026-11-experiments.md)."""

FOREGROUND_WIDTH = 8
"""The foreground U-Net's default width (its first stage's channels)."""

TASKS: dict[str, Task] = {"autoencoder": AutoencoderTask(), "image": ImageTask(), "completion": CompletionTask(),
                          "classify": ClassifyTask(), "foreground": ForegroundTask(), "refine": RefineTask()}


def encode_with_guide(model: nn.Module, cfg: TrainConfig, dataset, indices) -> tuple[torch.Tensor, Guide | None]:
    """Latent codes of shapes ``indices`` (:meth:`Task.encode`) and, for a guided completion
    model, the :class:`~model.decode.Guide` of their scans (evaluation views) to decode with."""
    if not cfg.skips:
        return TASKS[cfg.task].encode(model, cfg, dataset, indices), None
    return model.encode_octree(dataset.pairs(indices)[0])


def check_config(cfg: TrainConfig) -> None:
    """Raise ValueError naming the first setting of ``cfg`` that cannot train: its task's own
    settings, then the generic ones."""
    if cfg.task not in TASKS:
        raise ValueError(f"unknown task {cfg.task!r}; choose from {', '.join(TASKS)}")
    TASKS[cfg.task].check(cfg)
    cfg.check()
