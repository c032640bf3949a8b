"""The training loop: seeds, batches, (distributed) optimisation, validation, checkpoints.

Batches are prepared on the CPU (in the training process, or ``loader_workers`` processes ahead
of it) and moved to ``cfg.device``; a batch is a pure function of (seed, step) either way."""

from __future__ import annotations

import io
import json
import math
import multiprocessing as mp
import os
import pickle
import time
from collections import deque
from dataclasses import asdict
from pathlib import Path

import numpy as np
import torch
from torch import distributed as dist
from tqdm import tqdm

from ..files import atomic_path, json_text
from .config import INIT_FILE, STEPS_DIR, TrainConfig, config_from_dict, load_checkpoint, read_run, write_weights
from .data import RecordSet
from .tasks import TASKS, check_config


def build_model(cfg: TrainConfig) -> torch.nn.Module:
    return TASKS[cfg.task].build_model(cfg)


def to_device(inputs: tuple, device: torch.device) -> tuple:
    """A batch's model arguments on ``device`` (tensors, :class:`OctreeTensors` and dicts of
    tensors; None stays)."""
    return tuple(None if x is None else {k: v.to(device) for k, v in x.items()} if isinstance(x, dict)
                 else x.to(device) for x in inputs)


_LOADER: Trainer | None = None
"""The trainer whose batches a loader process prepares (set before the processes are forked)."""


class _ArrayPickler(pickle.Pickler):
    """Pickles CPU tensors as their NumPy arrays, a copy of their bytes (unpickled by
    ``torch.from_numpy``), instead of torch's serialisation of each storage, several times slower."""

    def reducer_override(self, obj):
        if type(obj) is torch.Tensor and obj.layout == torch.strided:
            try:
                return torch.from_numpy, (obj.numpy(),)
            except (TypeError, RuntimeError):     # a dtype NumPy lacks, a tensor needing grad, on a GPU
                pass
        return NotImplemented


def _prepared(call: tuple[str, int]) -> bytes:
    """``_LOADER.<method>(arg)`` in a loader process, pickled by value: torch's multiprocessing
    reducers would pass each tensor as a file descriptor, and a depth-7 batch holds hundreds."""
    method, arg = call
    buf = io.BytesIO()
    _ArrayPickler(buf, protocol=pickle.HIGHEST_PROTOCOL).dump(getattr(_LOADER, method)(arg))
    return buf.getvalue()


def _quiet_worker() -> None:
    torch.set_num_threads(1)


INIT_SETTINGS = ("latent", "channels", "pred_hidden", "decoder_blocks", "encoder", "encoder_width", "image_size",
                 "categories")
"""Settings that shape a network, named when ``--init``'s weights do not fit."""


def load_initial_weights(cfg: TrainConfig, model: torch.nn.Module) -> dict:
    """Load the weights of the run or checkpoint folder ``cfg.init`` into ``model``; returns their
    provenance (what RUN/init.json records).  ValueError when it is neither folder, of another task
    or architecture, or its tensors do not fit ``model``."""
    source = read_run(cfg.init)
    for key in ("task", "arch"):
        if getattr(source.config, key) != getattr(cfg, key):
            raise ValueError(f"--init {cfg.init} is a {key} {getattr(source.config, key)!r} run, not {getattr(cfg, key)!r}")
    try:
        model.load_state_dict(source.weights)
    except RuntimeError:                     # missing, unexpected or differently shaped tensors
        settings = ", ".join(f"{k}={getattr(source.config, k)!r}" for k in INIT_SETTINGS
                             if getattr(source.config, k) != getattr(cfg, k)) or "another network"
        raise ValueError(f"--init {cfg.init} does not fit this network: it was trained with {settings}") from None
    return {"path": cfg.init, "weights_sha256": source.meta.get("weights_sha256"), "steps": source.meta.get("steps")}


class Prefetcher:
    """The model inputs of steps ``start``, ``start+1``, ... prepared by forked processes, at most
    ``ahead`` in flight; :meth:`next` returns them in step order."""

    def __init__(self, trainer: Trainer, workers: int, start: int, stop: int):
        global _LOADER
        _LOADER = trainer
        self.trainer = trainer
        self.pool = mp.get_context("fork").Pool(workers, initializer=_quiet_worker)
        self.queue, self.next_step, self.stop, self.ahead = deque(), start, stop, 2 * workers
        self._fill()

    def _fill(self) -> None:
        while len(self.queue) < self.ahead and self.next_step < self.stop:
            self.queue.append(self.pool.apply_async(_prepared, (("step_inputs", self.next_step),)))
            self.next_step += 1

    def next(self) -> tuple:
        batch = self.queue.popleft().get()
        self._fill()
        return pickle.loads(batch)

    def validation(self):
        """The validation split's batches (no augmentation), in order, prepared by the processes."""
        for batch in self.pool.imap(_prepared, [("validation_inputs", s) for s in self.trainer.validation_starts()]):
            yield pickle.loads(batch)

    def close(self) -> None:
        self.pool.terminate()
        self.pool.join()


class Trainer:
    """One training run (one process of a distributed run when WORLD_SIZE > 1)."""

    def __init__(self, cfg: TrainConfig):
        check_config(cfg)
        self.cfg = cfg
        self.world = int(os.environ.get("WORLD_SIZE", "1"))
        self.rank = int(os.environ.get("RANK", "0"))
        self._owns_group = self.world > 1 and not dist.is_initialized()
        if self._owns_group:
            dist.init_process_group("gloo")
        if cfg.batch_size % self.world:
            raise ValueError(f"--batch-size {cfg.batch_size} must be a multiple of the {self.world} processes")
        self.task = TASKS[cfg.task]
        self.train_set = self.task.dataset(cfg, "train", cfg.seed, limit=cfg.limit)
        self.val_set: RecordSet | None
        try:
            self.val_set = self.task.dataset(cfg, "val", cfg.seed + 1, limit=cfg.limit)
        except ValueError as exc:
            if not str(exc).startswith("no records"):
                raise
            self.val_set = None
        if cfg.epochs is not None:
            cfg.iters = max(1, math.ceil(cfg.epochs * len(self.train_set) / cfg.batch_size))
        if cfg.until is not None and cfg.until > cfg.iters:
            raise ValueError(f"--until {cfg.until} is past the run's last step ({cfg.iters}); give at most that")
        self.end = cfg.iters if cfg.until is None else cfg.until   # the step this invocation trains to
        torch.manual_seed(cfg.seed)
        self.device = torch.device(cfg.device)
        self.model = build_model(cfg).to(self.device)
        self.net = self.model
        if self.world > 1:
            self.net = torch.nn.parallel.DistributedDataParallel(self.model)
        lr = cfg.lr if cfg.lr is not None else (1e-3 if cfg.optimizer == "adam" else 0.1)
        self.opt = (torch.optim.Adam(self.model.parameters(), lr=lr, weight_decay=cfg.weight_decay)
                    if cfg.optimizer == "adam" else
                    torch.optim.SGD(self.model.parameters(), lr=lr, momentum=0.9, weight_decay=cfg.weight_decay))
        # Paper schedule shape: divide the rate by 10 at 2/7, 4/7 and 5/7 of the run.
        marks = [int(cfg.iters * f) for f in (2 / 7, 4 / 7, 5 / 7)]
        self.sched = torch.optim.lr_scheduler.MultiStepLR(self.opt, milestones=marks, gamma=0.1)
        self.step = 0
        self.loader: Prefetcher | None = None     # batch-preparing processes while run() runs
        self.out = Path(cfg.out)
        if self.rank == 0:
            try:
                self.out.mkdir(parents=True, exist_ok=True)
            except OSError as exc:
                raise ValueError(f"cannot create the run folder {self.out}: {exc.strerror}") from None
        self._resume()

    # -- checkpoints ----------------------------------------------------------------------------
    @property
    def ckpt_path(self) -> Path:
        return self.out / "checkpoint.pt"

    def _resume(self) -> None:
        if not self.ckpt_path.is_file():
            provenance = load_initial_weights(self.cfg, self.model) if self.cfg.init is not None else None
            if self.rank == 0:
                if provenance is not None:
                    (self.out / INIT_FILE).write_text(json_text(provenance))
                (self.out / "config.json").write_text(json.dumps(asdict(self.cfg), indent=1) + "\n")
            return
        state = load_checkpoint(self.ckpt_path)
        saved = asdict(config_from_dict(state["config"]))
        for key in ("task", "arch", "depth", "latent", "channels", "batch_size", "seed", "structure_loss",
                    "pred_hidden", "decoder_blocks", "encoder", "encoder_width", "image_size", "categories",
                    "teacher", "up", "skips", "crop_share", "skeleton_weight", "init"):
            if saved[key] != getattr(self.cfg, key):
                raise ValueError(f"{self.ckpt_path} was trained with {key}={saved[key]!r}, not "
                                 f"{getattr(self.cfg, key)!r}; use another --out")
        self.model.load_state_dict(state["model"])
        self.opt.load_state_dict(state["optimizer"])
        self.sched.load_state_dict(state["scheduler"])
        self.step = state["step"]
        torch.set_rng_state(state["torch_rng"])
        if self.device.type == "cuda" and state.get("cuda_rng") is not None:
            torch.cuda.set_rng_state(state["cuda_rng"], self.device)

    def save(self) -> None:
        if self.rank != 0:
            return
        with atomic_path(self.ckpt_path) as tmp:
            cuda_rng = torch.cuda.get_rng_state(self.device) if self.device.type == "cuda" else None
            torch.save({"model": {k: v.cpu() for k, v in self.model.state_dict().items()},
                        "optimizer": self.opt.state_dict(), "scheduler": self.sched.state_dict(),
                        "step": self.step, "torch_rng": torch.get_rng_state(), "cuda_rng": cuda_rng,
                        "config": asdict(self.cfg)}, tmp)

    def snapshot(self, validation: dict[str, float]) -> None:
        """Keep this step's weights as a checkpoint folder ``RUN/steps/<step>/`` (half precision,
        with the validation losses): the validated steps a checkpoint can be chosen among
        (``python -m research.curves --chamfer`` measures each)."""
        if self.rank != 0:
            return
        config = {k: v for k, v in asdict(self.cfg).items() if k not in ("out", "progress")}
        weights = {k: v.cpu() for k, v in self.model.state_dict().items()}
        write_weights(self.out / STEPS_DIR / f"{self.step:06d}", weights,
                      {"config": config, "steps": self.step, "validation": validation})

    # -- batches ----------------------------------------------------------------------------------
    def batch_indices(self, step: int) -> np.ndarray:
        """This process's shapes of global step ``step``: a pure function of (seed, step), so a
        resumed run sees exactly the batches it would have seen."""
        n = len(self.train_set)
        per_epoch = max(1, n // self.cfg.batch_size)
        epoch, k = divmod(step, per_epoch)
        order = np.random.default_rng([self.cfg.seed, epoch]).permutation(n)
        if n < self.cfg.batch_size:
            order = np.resize(order, self.cfg.batch_size)
        chosen = order[k * self.cfg.batch_size:(k + 1) * self.cfg.batch_size]
        return chosen[self.rank::self.world]

    def step_inputs(self, step: int) -> tuple:
        """The model inputs (on the CPU) of training step ``step``: its shapes and augmentation
        are a function of (seed, step)."""
        rng = np.random.default_rng([self.cfg.seed, step, 1])
        return self.task.inputs(self.cfg, self.train_set, self.batch_indices(step), rng)

    def validation_starts(self) -> range:
        """The first index of each validation batch."""
        return range(0, len(self.val_set), self.cfg.batch_size)

    def validation_inputs(self, start: int) -> tuple:
        """The model inputs (on the CPU, no augmentation) of the validation batch from ``start``."""
        idx = np.arange(start, min(len(self.val_set), start + self.cfg.batch_size))
        return self.task.inputs(self.cfg, self.val_set, idx, None)

    def forward(self, inputs: tuple, net: torch.nn.Module | None = None) -> dict[str, torch.Tensor]:
        """The losses of prepared inputs, on the training device (autocast with ``cfg.amp``);
        float32 losses."""
        with torch.autocast(self.device.type, dtype=torch.bfloat16, enabled=self.cfg.amp):
            out = (net or self.net)(*to_device(inputs, self.device))
        return {k: v.float() for k, v in out.items()}

    def losses(self, dataset: RecordSet, indices, rng: np.random.Generator | None = None) -> dict[str, torch.Tensor]:
        """The model's losses on shapes ``indices`` (random augmentation drawn from ``rng``)."""
        return self.forward(self.task.inputs(self.cfg, dataset, indices, rng))

    # -- the loop ---------------------------------------------------------------------------------
    def train_step(self, inputs: tuple | None = None) -> dict[str, float]:
        """One optimisation step on ``inputs`` (default: prepared here for the current step)."""
        self.model.train()
        loss = self.forward(self.step_inputs(self.step) if inputs is None else inputs)
        self.opt.zero_grad(set_to_none=True)
        loss["total"].backward()
        self.opt.step()
        self.sched.step()
        self.step += 1
        return {k: float(v.detach()) for k, v in loss.items()}

    @torch.no_grad()
    def validate(self) -> dict[str, float]:
        """Mean losses over the validation split (teacher forcing, batch statistics frozen).

        Runs on a forked, fixed-seed torch RNG: decoders that sample (AtlasNet's uv points) give
        the same validation loss every time and leave the training's random stream untouched, so
        a resumed run matches an uninterrupted one whether or not it validated in between."""
        self.model.eval()
        sums: dict[str, float] = {}
        n, starts = len(self.val_set), self.validation_starts()
        batches = self.loader.validation() if self.loader is not None else map(self.validation_inputs, starts)
        with torch.random.fork_rng(devices=[self.device] if self.device.type == "cuda" else []):
            torch.manual_seed(self.cfg.seed)
            for s, inputs in zip(starts, batches):
                out = self.forward(inputs, self.model)
                for k, v in out.items():
                    sums[k] = sums.get(k, 0.0) + float(v) * (min(n, s + self.cfg.batch_size) - s)
        return {k: v / n for k, v in sums.items()}

    def log(self, row: dict) -> None:
        if self.rank == 0:
            with open(self.out / "metrics.jsonl", "a") as fh:
                fh.write(json_text(row, indent=None) + "\n")

    def close(self) -> None:
        """End this process's part of a distributed run: wait for the others, then destroy the
        process group this trainer started (a process that exits with it alive may abort in
        gloo's teardown).  Nothing to do in one process; calling it twice is harmless."""
        if self._owns_group and dist.is_initialized():
            dist.barrier()
            dist.destroy_process_group()
        self._owns_group = False

    def run(self) -> dict:
        """Train to step :attr:`end` (already past it: no step); returns (and on rank 0 prints) a one-line summary."""

        bar = tqdm(total=self.end, initial=self.step, desc=f"{self.cfg.task} {self.cfg.arch}", unit="step",
                   disable=not self.cfg.progress or self.rank != 0)
        t0, start = time.time(), self.step
        summary: dict = {"run": str(self.out)}
        self.loader = (Prefetcher(self, self.cfg.loader_workers, self.step, self.end)
                       if self.cfg.loader_workers > 0 and self.step < self.end else None)
        try:
            self._loop(bar, t0, summary)
            summary["steps"] = self.step                            # end, or where it is when already past
        finally:
            if self.loader is not None:
                self.loader.close()
                self.loader = None
        bar.close()
        summary["seconds"] = time.time() - t0
        if self.rank == 0:
            print(summary_line(summary, self.step - start, self.ckpt_path), flush=True)
        return summary

    def _loop(self, bar, t0: float, summary: dict) -> None:
        while self.step < self.end:
            losses = self.train_step(None if self.loader is None else self.loader.next())
            summary["train"] = losses
            bar.update()
            bar.set_postfix(loss=f"{losses['total']:.4f}")
            if self.step % 10 == 0 or self.step == self.end:
                self.log({"step": self.step, "split": "train", "lr": self.sched.get_last_lr()[0],
                          "seconds": time.time() - t0, **losses})
            due = self.step % self.cfg.val_every == 0 or self.step == self.end
            if self.val_set is not None and due and self.rank == 0:   # one process validates
                summary["val"] = self.validate()
                self.log({"step": self.step, "split": "val", **summary["val"]})
                self.snapshot(summary["val"])
            if self.step % self.cfg.ckpt_every == 0 or self.step == self.end:
                self.save()


def summary_line(summary: dict, trained: int, ckpt: Path) -> str:
    """One line for the end of a run: what was trained, how long, the last losses."""
    if trained == 0:
        return f"{summary['run']}: already trained to step {summary['steps']} ({ckpt})"
    text = f"{summary['run']}: trained {trained} steps to step {summary['steps']} in {summary['seconds']:.0f} s"
    if "train" in summary:
        text += f", last train loss {summary['train']['total']:.4f}"
    if "val" in summary:
        text += f", validation loss {summary['val']['total']:.4f}"
    return text + f"; checkpoint {ckpt}"
