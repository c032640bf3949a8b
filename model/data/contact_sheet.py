"""Contact sheets: grids of rendered procedural shapes, one PNG per category plus an overview.

Used to eyeball that generated shapes look like their category and vary.
Run ``python -m model.data.contact_sheet --out DIR``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from PIL import Image, ImageDraw

from ..cli import command_parser
from .render import render
from .shapes import CATEGORIES, GENERATORS, generate


def sheet(
    categories: tuple[str, ...] | list[str],
    n_per_category: int,
    seed: int = 0,
    tile: int = 128,
    azimuth_deg: float = 35.0,
    elevation_deg: float = 25.0,
    label: bool = True,
    generator: int = 1,
) -> Image.Image:
    """Grid image with one row per category and ``n_per_category`` shapes per row.

    Each shape is rendered on white at a fixed 3/4 view so shapes are comparable.
    """
    label_w = 90 if label else 0
    img = Image.new("RGB", (label_w + tile * n_per_category, tile * len(categories)), (255, 255, 255))
    draw = ImageDraw.Draw(img)
    for r, cat in enumerate(categories):
        if label:
            draw.text((4, r * tile + tile // 2 - 6), cat, fill=(0, 0, 0))
        for c in range(n_per_category):
            mesh = generate(cat, c, seed, generator)
            rgba, _ = render(mesh, azimuth_deg, elevation_deg, 2.6, size=tile, supersample=2,
                             color=(0.55, 0.62, 0.75))
            a = rgba[..., 3:4].astype(np.float64) / 255.0
            rgb = rgba[..., :3] * a + 255.0 * (1 - a)
            img.paste(Image.fromarray(rgb.astype(np.uint8)), (label_w + c * tile, r * tile))
    return img


def write_sheets(out: Path, n_per_category: int = 12, overview_n: int = 6, seed: int = 0, tile: int = 128,
                 generator: int = 1, categories: tuple[str, ...] = CATEGORIES) -> list[Path]:
    """Write contact_sheet_<category>.png (one row per sheet, wrapped) and contact_sheet_overview.png."""
    out.mkdir(parents=True, exist_ok=True)
    paths = []
    for cat in categories:
        img = sheet([cat], n_per_category, seed=seed, tile=tile, generator=generator)
        path = out / f"contact_sheet_{cat}.png"
        img.save(path, optimize=True)
        paths.append(path)
    path = out / "contact_sheet_overview.png"
    sheet(categories, overview_n, seed=seed, tile=tile, generator=generator).save(path, optimize=True)
    paths.append(path)
    return paths


def main(argv: list[str] | None = None) -> None:
    """Command-line entry point: write contact sheets into --out."""
    p = command_parser("python -m model.data.contact_sheet", __doc__, [
        "python -m model.data.contact_sheet --out sheets/"])
    p.add_argument("--out", type=Path, required=True, help="folder for the sheets (PNG)")
    p.add_argument("--n", type=int, default=12, help="shapes per category sheet (default 12)")
    p.add_argument("--overview-n", type=int, default=6, help="shapes per category on the overview (default 6)")
    p.add_argument("--seed", type=int, default=0, help="seed of the shapes (default 0)")
    p.add_argument("--tile", type=int, default=128, help="side of each rendered tile in pixels (default 128)")
    p.add_argument("--generator", type=int, choices=sorted(GENERATORS), default=1,
                   help="version of the generators (default 1)")
    p.add_argument("--categories", nargs="+", choices=CATEGORIES, default=list(CATEGORIES),
                   help="only these categories (default all)")
    args = p.parse_args(argv)
    for path in write_sheets(args.out, args.n, args.overview_n, args.seed, args.tile, args.generator,
                             tuple(args.categories)):
        print(path)


if __name__ == "__main__":
    main()
