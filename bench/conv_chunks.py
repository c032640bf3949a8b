"""The eager octree convolution's chunk size on the CPU: a training step's time against the bytes of
neighbour rows gathered per GEMM.

``model.nn.ops.octree_conv`` gathers the neighbour rows of a chunk of octants, then multiplies them
by the kernel in one GEMM (forward, and twice in the hand-written backward).  This times one
autoencoder training step of each of ``--archs`` (forward, backward, Adam; the batch of
``bench.train_step``: ``--batch`` procedural scans, one per category in turn, in the arch's
octrees: adaptive for Adaptive O-CNN, full for the O-CNN baselines) with each chunk size
in ``--chunks`` (MiB), interleaved round by round (one warm-up round, then the median of
``--repeats``), at each thread count of ``--threads``, and prints the ratio of each to the
previous setting (16 MiB) measured in the same run.  The kept setting is
``model.nn.ops.CPU_CHUNK_BYTES``.

    python -m bench.conv_chunks [--archs aocnn] [--depths 6 7] [--chunks 0.5 1 2 4 16] [--threads 1 2]
                                [--repeats 5]
"""

from __future__ import annotations

import statistics
import sys
import time

from bench.octree_build import table, torch_threads
from bench.train_step import training_batch
from model.cli import command_parser
from model.networks.autoencoder import ARCHS

OCTREE_ARCHS = tuple(name for name, arch in ARCHS.items() if arch.decoder != "psg")
"""The octree autoencoders (the point-set baseline's decoder has no octree convolution)."""
REFERENCE_MIB = 16.0
"""The chunk size of every CPU training before CPU_CHUNK_BYTES: the ratios' reference."""


def step_times(arch: str, depth: int, batch: int, chunks: list[float], threads: int,
               repeats: int) -> dict[float, float]:
    """Median seconds of one autoencoder training step of ``arch`` at ``depth`` per chunk size (MiB)."""
    import torch

    from model.networks import Autoencoder
    from model.nn import ops

    octree = training_batch(ARCHS[arch].octree == "adaptive", depth, batch)
    torch.manual_seed(0)
    model = Autoencoder(arch, depth, base_channels=8)
    opt = torch.optim.Adam(model.parameters(), 1e-3)
    kept, times = ops.CPU_CHUNK_BYTES, {c: [] for c in chunks}
    try:
        with torch_threads(threads):
            for rnd in range(repeats + 1):
                for c in chunks:
                    ops.CPU_CHUNK_BYTES = int(c * 2 ** 20)
                    t = time.perf_counter()
                    loss = model(octree)["total"]
                    opt.zero_grad()
                    loss.backward()
                    opt.step()
                    if rnd > 0:
                        times[c].append(time.perf_counter() - t)
    finally:
        ops.CPU_CHUNK_BYTES = kept
    return {c: statistics.median(t) for c, t in times.items()}


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.conv_chunks", __doc__, ["python -m bench.conv_chunks --depths 7 --threads 1"])
    ap.add_argument("--archs", nargs="+", default=["aocnn"], choices=OCTREE_ARCHS,
                    help="autoencoder architectures (default aocnn)")
    ap.add_argument("--depths", type=int, nargs="+", default=[6, 7], help="octree depths (default 6 7)")
    ap.add_argument("--batch", type=int, default=8, help="shapes per step (default 8, as the trainings)")
    ap.add_argument("--chunks", type=float, nargs="+", default=[0.5, 1, 2, 4, 16],
                    help="chunk sizes in MiB (default 0.5 1 2 4 16)")
    ap.add_argument("--threads", type=int, nargs="+", default=[1, 2], help="torch thread counts (default 1 2)")
    ap.add_argument("--repeats", type=int, default=5, help="timed rounds after a warm-up (default 5)")
    args = ap.parse_args(argv)
    if min(args.chunks) <= 0 or min(args.threads) < 1 or args.repeats < 1 or args.batch < 1:
        ap.error("chunks must be positive, threads, repeats and batch at least 1")
    from model.nn.ops import CPU_CHUNK_BYTES

    chunks = sorted(set(args.chunks) | {REFERENCE_MIB})
    print(f"autoencoder training step (batch {args.batch}), median of {args.repeats} interleaved rounds; "
          f"kept: {CPU_CHUNK_BYTES / 2 ** 20:g} MiB; ratio: against {REFERENCE_MIB:g} MiB in the same run")
    rows = []
    for arch in args.archs:
        for depth in args.depths:
            for threads in args.threads:
                t = step_times(arch, depth, args.batch, chunks, threads, args.repeats)
                rows += [[arch, depth, threads, f"{c:g}", f"{1e3 * t[c]:.0f}", f"{t[c] / t[REFERENCE_MIB]:.2f}"]
                         for c in chunks]
    print(table(["arch", "depth", "threads", "chunk MiB", "step ms", "ratio"], rows))
    return 0


if __name__ == "__main__":
    sys.exit(main())
