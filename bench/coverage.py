"""How close the procedural generators come to real shapes: for each real mesh of a known category
(:data:`bench.photos.REAL_MESHES` found in ``--meshes``), the Chamfer distance to the nearest of
``--shapes`` generated shapes of its category, for every generator version, in the same run.

A real shape far from every generated one is a kind the generator does not make, and so a kind
the models never train on.  Shapes are compared as the dataset holds them (centred, longest
bounding-box edge 1, y up): ``--points`` samples drawn by area from each mesh, the distance the
least over the four quarter turns about the vertical axis (the real meshes face any way).  The
generated shapes come from ``--seed``, a seed no dataset is built with.  The table gives, per
real mesh and version, the nearest shape's Chamfer (x10^3), the mean of the 5 nearest, and the
ratio of each version's nearest to the first version's.

    python -m bench.coverage --meshes ../shared/meshes [--shapes 200] [--figure coverage.png]
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import trimesh

from model.cli import command_parser
from model.data.shapes import GENERATORS, generate
from model.octree.metrics import chamfer_distance

SEED = 314159
"""The generated shapes' seed: used by no dataset, no test and no evaluation."""

NEAREST = 5


def surface_points(mesh: trimesh.Trimesh, n: int, seed: int) -> np.ndarray:
    """``n`` points drawn by area from ``mesh`` (a fixed draw for a fixed ``seed``)."""
    points, _ = trimesh.sample.sample_surface(mesh, n, seed=seed)
    return np.asarray(points)


def quarter_turns(points: np.ndarray) -> list[np.ndarray]:
    """``points`` turned by 0, 90, 180 and 270 degrees about the vertical (y) axis."""
    x, y, z = points.T
    return [points, np.c_[z, y, -x], np.c_[-x, y, -z], np.c_[-z, y, x]]


def nearest(real: np.ndarray, generated: list[np.ndarray]) -> np.ndarray:
    """Chamfer distance of ``real`` to each generated point set, the least over quarter turns."""
    turns = quarter_turns(real)
    return np.array([min(chamfer_distance(t, g) for t in turns) for g in generated])


def main(argv: list[str] | None = None) -> int:
    p = command_parser("python -m bench.coverage", __doc__, [
        "python -m bench.coverage --meshes ../shared/meshes --shapes 200"])
    p.add_argument("--meshes", type=Path, required=True, help="a folder with the real meshes")
    p.add_argument("--shapes", type=int, default=200, help="generated shapes per category and version (default 200)")
    p.add_argument("--points", type=int, default=4096, help="samples per mesh (default 4096)")
    p.add_argument("--seed", type=int, default=SEED, help=f"seed of the generated shapes (default {SEED})")
    p.add_argument("--figure", type=Path, default=None,
                   help="PNG: each real mesh beside its nearest generated shape of every version")
    args = p.parse_args(argv)
    from .photos import real_meshes

    if not args.meshes.is_dir():
        print(f"error: --meshes {args.meshes} is not a folder", file=sys.stderr)
        return 2
    if args.shapes < NEAREST or args.points < 64:
        print(f"error: --shapes must be at least {NEAREST} and --points at least 64", file=sys.stderr)
        return 2
    reals = real_meshes(args.meshes)
    if not reals:
        print(f"error: none of the real meshes is in {args.meshes}", file=sys.stderr)
        return 2
    versions = sorted(GENERATORS)
    pools: dict[tuple[str, int], list[np.ndarray]] = {}
    rows, tiles = [], []
    for name, category, mesh in reals:
        real = surface_points(mesh, args.points, 0)
        row = [name, category]
        best = []
        for v in versions:
            if (category, v) not in pools:
                pools[category, v] = [surface_points(generate(category, i, args.seed, v), args.points, i)
                                      for i in range(args.shapes)]
            d = nearest(real, pools[category, v]) * 1e3
            order = np.argsort(d)
            best.append((v, int(order[0]), float(d[order[0]])))
            row += [f"{d[order[0]]:.2f}", f"{d[order[:NEAREST]].mean():.2f}"]
        row += [f"{b[2] / best[0][2]:.2f}" for b in best[1:]]
        rows.append(row)
        tiles.append((mesh, category, best))
    head = ["real mesh", "category"] + [f"v{v} {w}" for v in versions for w in ("nearest", f"{NEAREST} nearest")]
    head += [f"v{v} / v1" for v in versions[1:]]
    print(f"Chamfer x10^3 to the nearest of {args.shapes} generated shapes (seed {args.seed}), "
          f"{args.points} points each, least over quarter turns")
    print("| " + " | ".join(head) + " |")
    print("|" + "---|" * len(head))
    for row in rows:
        print("| " + " | ".join(row) + " |")
    if args.figure:
        draw_figure(args.figure, tiles, args.seed)
        print(f"figure: {args.figure}")
    return 0


def draw_figure(path: Path, tiles, seed: int, side: int = 160) -> None:
    """One row per real mesh: the mesh, then its nearest generated shape of every version."""
    from PIL import Image

    from model.data.render import render
    from model.image.frame import composite

    def picture(mesh):
        rgba, _ = render(mesh, 35.0, 25.0, 2.8, size=side, color=(0.55, 0.62, 0.75))
        return composite(rgba, (255, 255, 255))

    rows = [np.concatenate([picture(mesh)] + [picture(generate(category, i, seed, v)) for v, i, _ in best], 1)
            for mesh, category, best in tiles]
    Image.fromarray(np.concatenate(rows, 0)).save(path)


if __name__ == "__main__":
    sys.exit(main())
