"""Train a network of the paper on a built dataset: classification (section 5.1), an autoencoder
or shape completion (section 5.2), or shape from a single image (section 5.3); and the foreground
network that finds the object in a photo before the image model sees it.

    python -m model.train autoencoder --data DIR --depth D --arch {aocnn,ocnn-binary,ocnn-patch,
        ocnn-patch-star,psg} --out RUN [--iters N] [--batch-size B] [--lr LR] [--optimizer adam|sgd]
    python -m model.train image --data DIR --depth D --encoder {resnet18,lenet}
        --decoder {aocnn,psg,atlasnet} --out RUN [...]
    python -m model.train completion --data DIR --depth D --arch {aocnn,ocnn-patch,...} --out RUN [...]
    python -m model.train classify --data DIR --depth D --arch {aocnn,ocnn} [--up y] --out RUN [...]
    python -m model.train foreground --data DIR --depth D --out RUN [--width 8] [--image-size 128] [...]

Progress bar with the loss, validation every --val-every steps, checkpoints written atomically
to RUN/checkpoint.pt (a rerun resumes from it), metrics appended to RUN/metrics.jsonl, fixed
seeds.  ``--device cuda`` trains on a GPU (batches prepared on the CPU, by ``--loader-workers``
processes ahead of the network).  Several processes train data-parallel (DDP, gloo) when started with
``torchrun --nproc_per_node K -m model.train ...``: each takes its share of every batch.
"""

from __future__ import annotations

import argparse
import sys

import torch

from ..cli import command_parser
from ..networks import ARCHS, IMAGE_DECODERS, IMAGE_ENCODERS
from ..networks.classifier import CLASSIFIER_ARCHS
from ..networks.decoder import STRUCTURE_LOSSES
from ..networks.foreground import FOREGROUND_ARCHS
from .classify import UP_AXES
from .loop import TrainConfig, Trainer
from .tasks import COMPLETION_ARCHS


def common_options() -> argparse.ArgumentParser:
    """Options every task takes."""
    c = argparse.ArgumentParser(add_help=False)
    c.add_argument("--data", required=True, help="dataset folder built by python -m model.data build")
    c.add_argument("--depth", type=int, required=True, help="octree depth (must match the dataset)")
    c.add_argument("--out", required=True, help="run folder: checkpoint, metrics, config (rerun to resume)")
    c.add_argument("--iters", type=int, default=2000, help="training steps (default 2000)")
    c.add_argument("--epochs", type=float, default=None, help="alternative to --iters: passes over the training split")
    c.add_argument("--until", type=int, default=None, metavar="STEP",
                   help="end the run at this step (default: the last, --iters); the rate schedule still spans "
                        "--iters, so the run is the full run's first STEP steps, and rerunning without it goes on")
    c.add_argument("--batch-size", type=int, default=8, help="shapes per step over all processes (default 8)")
    c.add_argument("--optimizer", choices=("adam", "sgd"), default="adam",
                   help="adam (default) or sgd with momentum 0.9 (the paper's); the rate drops 10x at 2/7, 4/7, 5/7")
    c.add_argument("--lr", type=float, default=None, help="learning rate (default 1e-3 adam, 0.1 sgd)")
    c.add_argument("--weight-decay", type=float, default=0.0, help="L2 weight decay (default 0; the paper: 5e-4 with SGD)")
    c.add_argument("--val-every", type=int, default=200, help="validate every this many steps (default 200)")
    c.add_argument("--ckpt-every", type=int, default=100, help="write RUN/checkpoint.pt every this many steps (default 100)")
    c.add_argument("--latent", type=int, default=128, help="latent code size (default 128, the paper's)")
    c.add_argument("--channels", type=int, default=8, help="octree channels at the max depth, doubling upward to 64 (default 8)")
    c.add_argument("--structure-loss", choices=STRUCTURE_LOSSES, default="balanced",
                   help="octree status loss per depth: balanced (default; each class weighted by its inverse "
                        "frequency), ce (the paper's cross-entropy) or focal")
    c.add_argument("--pred-hidden", type=int, default=32, help="prediction module width (default 32; the paper: 8)")
    c.add_argument("--decoder-blocks", type=int, default=1,
                   help="octree decoder convolutions per depth (default 1, the paper's)")
    c.add_argument("--categories", nargs="+", default=None, help="train on these categories only (default all)")
    c.add_argument("--seed", type=int, default=0, help="seed of weights, batch order and augmentation (default 0)")
    c.add_argument("--threads", type=int, default=None, help="torch threads per process (default: torch's)")
    c.add_argument("--limit", type=int, default=None, help="use at most this many shapes per split (default all)")
    c.add_argument("--quiet", action="store_true", help="no progress bar")
    c.add_argument("--workers", type=int, default=1,
                   help="processes reading the dataset (and building a task's octree cache beside it on "
                        "first use; default 1)")
    c.add_argument("--loader-workers", type=int, default=0,
                   help="processes preparing the next batches while the network trains (default 0: "
                        "prepared in the training process); the batches are the same either way")
    c.add_argument("--device", default="cpu",
                   help="where the network trains: cpu (default), cuda or cuda:N; batches are prepared on the CPU")
    c.add_argument("--amp", action="store_true",
                   help="mixed precision: the forward pass in bfloat16 autocast (default: float32)")
    c.add_argument("--init", default=None,
                   help="a run or checkpoint folder of the same task and network whose weights a new run "
                        "starts from (fine-tuning; optimizer and schedule start afresh; default: random weights)")
    return c


def add_stream(parser: argparse.ArgumentParser) -> None:
    """The --stream option of the tasks whose splits can be read as batches need them."""
    parser.add_argument("--stream", type=int, default=0, metavar="N",
                        help="read each split's records from the dataset (and its cache) as batches need them, "
                             "keeping the last N shapes in memory, instead of holding the whole split (for "
                             "datasets larger than memory; the same batches; default 0: the whole split)")


def parse_args(argv: list[str] | None) -> argparse.Namespace:
    ap = command_parser("python -m model.train", __doc__, [
        "python -m model.train autoencoder --data data/procedural --depth 6 --arch aocnn --out runs/aocnn --iters 4000",
        "python -m model.train image --data data/procedural --depth 6 --encoder resnet18 --decoder aocnn --out runs/img",
        "python -m model.train classify --data data/procedural --depth 6 --arch aocnn --out runs/cls --batch-size 16"])
    sub = ap.add_subparsers(dest="task", required=True)
    common = common_options()
    a = sub.add_parser("autoencoder", parents=[common], help="train a 3D autoencoder (paper section 5.2)")
    a.add_argument("--arch", choices=sorted(ARCHS), default="aocnn",
                   help="aocnn (default): Adaptive O-CNN; ocnn-binary / ocnn-patch / ocnn-patch-star: the "
                        "full-octree ablation; psg: point-set decoder")
    i = sub.add_parser("image", parents=[common], help="train shape from a single image (paper section 5.3)")
    i.add_argument("--encoder", choices=IMAGE_ENCODERS, default="resnet18", help="image encoder (default resnet18)")
    i.add_argument("--encoder-width", type=int, default=None,
                   help="encoder width: resnet18's first stage (default 32), lenet's first conv (default 20)")
    i.add_argument("--decoder", dest="arch", choices=IMAGE_DECODERS, default="aocnn",
                   help="aocnn (default): Adaptive O-CNN; psg: point set; atlasnet: 25 square patches")
    i.add_argument("--image-size", type=int, default=128, help="encoder input side in pixels (default 128)")
    i.add_argument("--background-share", type=float, default=0.5,
                   help="share of samples composited onto a random background (default 0.5)")
    i.add_argument("--teacher", default=None,
                   help="an aocnn autoencoder run: regress the encoder onto its latent codes and use its "
                        "decoder; or an image run or checkpoint: start from it and regress onto its codes "
                        "of the clean renders (default: train encoder and decoder end to end)")
    i.add_argument("--photo-share", type=float, default=0.0,
                   help="share of samples made photos (a scene, no alpha) and cut out again with an "
                        "imperfect mask, as the service's background removal does (default 0)")
    i.add_argument("--foreground-ratio", type=float, default=None,
                   help="share of the encoder's square the object's longest side fills (default 0.9)")
    f = sub.add_parser("foreground", parents=[common],
                       help="train the foreground network that finds the object in a photo (background removal)")
    f.add_argument("--arch", choices=tuple(FOREGROUND_ARCHS), default="unet",
                   help="unet (default): a compact U-Net; unet-lite: a U-Net whose work is at half the input's "
                        "resolution and coarser, about a fifth of unet's at the same width")
    f.add_argument("--width", dest="encoder_width", type=int, default=None,
                   help="the network's width: the channels of its first two-convolution stage, doubling per "
                        "stage up to 8x (default 8)")
    f.add_argument("--crop-share", type=float, default=0.0,
                   help="share of the samples that are a second look's view: the object's square cut from "
                        "the photo, as the service looks again at a small object (default 0)")
    f.add_argument("--skeleton-weight", type=float, default=0.0,
                   help="weight of the skeleton recall loss: the share of each target's thinned object "
                        "(legs, slats, a wing's edge) the mask misses (default 0: none)")
    f.add_argument("--image-size", type=int, default=128,
                   help="the network's input side: photos are resized to it (default 128, a multiple of 16; "
                        "of 32 for unet-lite)")
    r = sub.add_parser("refine", parents=[common],
                       help="train the foreground refinement network: the object's square of a photo segmented "
                            "again at its own resolution, with the first network's mask as a fourth channel")
    r.add_argument("--teacher", required=True,
                   help="the first foreground network (a foreground run or checkpoint) whose served mask the "
                        "refinement starts from")
    r.add_argument("--arch", choices=tuple(FOREGROUND_ARCHS), default="unet-lite",
                   help="unet-lite (default) or unet, as for the foreground network")
    r.add_argument("--width", dest="encoder_width", type=int, default=16,
                   help="the network's width (default 16)")
    r.add_argument("--skeleton-weight", type=float, default=1.0,
                   help="weight of the skeleton recall loss (default 1: thin parts count as much as the body)")
    r.add_argument("--image-size", type=int, default=256,
                   help="the side the object's square is resized to (default 256, a multiple of 32 for unet-lite)")
    c = sub.add_parser("completion", parents=[common],
                       help="train shape completion from partial scans (paper section 5.2)")
    c.add_argument("--arch", choices=COMPLETION_ARCHS, default="aocnn",
                   help="aocnn (default): Adaptive O-CNN; ocnn-patch (the paper's baseline), ocnn-patch-star, "
                        "ocnn-binary: O-CNN on full octrees")
    c.add_argument("--skips", action="store_true",
                   help="output-guided skip connections: each decoded octant also reads the encoder's "
                        "features of the scan's octant with the same key (Wang, Liu, Tong, CVPRW 2020)")
    for parser in (a, i, f, c):
        add_stream(parser)
    k = sub.add_parser("classify", parents=[common], help="train shape classification (paper section 5.1)")
    k.add_argument("--arch", choices=sorted(CLASSIFIER_ARCHS), default="aocnn",
                   help="aocnn (default): Adaptive O-CNN on the adaptive octree; ocnn: O-CNN on the full octree")
    k.add_argument("--up", choices=UP_AXES, default="y",
                   help="the shapes' up axis, the axis of the 12 training rotations (default y, as the "
                        "procedural shapes and ShapeNet; ModelNet40's meshes are z-up)")
    return ap.parse_args(argv)


def main(argv: list[str] | None = None) -> int:
    args = parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    fields = set(TrainConfig.__dataclass_fields__) - {"progress"}
    cfg = TrainConfig(**{k: v for k, v in vars(args).items() if k in fields}, progress=not args.quiet)
    try:
        trainer = Trainer(cfg)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    try:
        trainer.run()
    finally:
        trainer.close()
    return 0


if __name__ == "__main__":
    sys.exit(main())
