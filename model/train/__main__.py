"""Train an autoencoder of paper section 5.2 on a built dataset.

    python -m model.train autoencoder --data DIR --depth D --arch {aocnn,ocnn-binary,ocnn-patch,
        ocnn-patch-star,psg} --out RUN [--iters N] [--batch-size B] [--lr LR] [--optimizer adam|sgd]

Progress bar with the loss, validation every --val-every steps, checkpoints written atomically
to RUN/checkpoint.pt (a rerun resumes from it), metrics appended to RUN/metrics.jsonl, fixed
seeds.  Several processes train data-parallel (DDP, gloo) when started with
``torchrun --nproc_per_node K -m model.train ...``: each takes its share of every batch.
"""

from __future__ import annotations

import argparse
import sys

import torch

from ..networks import ARCHS
from .loop import TrainConfig, Trainer


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = argparse.ArgumentParser(prog="python -m model.train", description=__doc__.splitlines()[0])
    sub = ap.add_subparsers(dest="task", required=True)
    a = sub.add_parser("autoencoder", help="train a 3D autoencoder")
    a.add_argument("--data", required=True, help="dataset folder built by python -m model.data build")
    a.add_argument("--depth", type=int, required=True, help="octree depth (must match the dataset)")
    a.add_argument("--arch", choices=sorted(ARCHS), default="aocnn")
    a.add_argument("--out", required=True, help="run folder: checkpoint, metrics, config")
    a.add_argument("--iters", type=int, default=2000, help="training steps")
    a.add_argument("--epochs", type=float, default=None, help="alternative to --iters: passes over the training split")
    a.add_argument("--batch-size", type=int, default=8, help="shapes per step (over all processes)")
    a.add_argument("--optimizer", choices=("adam", "sgd"), default="adam")
    a.add_argument("--lr", type=float, default=None, help="learning rate (default 1e-3 adam, 0.1 sgd)")
    a.add_argument("--weight-decay", type=float, default=0.0, help="(the paper used 5e-4 with SGD)")
    a.add_argument("--val-every", type=int, default=200)
    a.add_argument("--ckpt-every", type=int, default=100)
    a.add_argument("--latent", type=int, default=128)
    a.add_argument("--channels", type=int, default=8, help="channels at the max depth (doubling upward)")
    a.add_argument("--seed", type=int, default=0)
    a.add_argument("--threads", type=int, default=None, help="torch threads per process")
    a.add_argument("--limit", type=int, default=None, help="use at most this many shapes per split")
    a.add_argument("--quiet", action="store_true")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    cfg = TrainConfig(data=args.data, depth=args.depth, arch=args.arch, out=args.out, iters=args.iters,
                      epochs=args.epochs, batch_size=args.batch_size, optimizer=args.optimizer,
                      lr=args.lr, weight_decay=args.weight_decay, val_every=args.val_every,
                      ckpt_every=args.ckpt_every, latent=args.latent, channels=args.channels,
                      seed=args.seed, limit=args.limit, progress=not args.quiet)
    try:
        trainer = Trainer(cfg)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    trainer.run()
    return 0


if __name__ == "__main__":
    sys.exit(main())
