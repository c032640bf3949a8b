"""Pictures of real outputs for docs/journal/2026-11-experiments.md, drawn with the project's own renderer.

    python -m research.figures --data DIR --runs NAME=RUN [NAME=RUN ...] --out PNG [--split test]
                            [--shapes 6] [--categories car chair ...] [--keep-scan]

One row per test shape: the input (the encoder's view for image models, the partial scan for
completion models), the truth (its adaptive octree's patches; for completion in the scan's frame),
each run's output (patch meshes; point sets as small splats; AtlasNet's
patches as grid meshes), and the first run's patches coloured by octree depth.  ``--keep-scan``
draws completion outputs as the service sends them by default (:func:`model.octree.fuse.keep_scan`
with each run's recorded empty bias).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np
import torch
import trimesh
from PIL import Image, ImageDraw

from model.checkpoint import load_model
from model.cli import command_parser
from model.data.render import render
from model.decode import Guide, empty_bias_of
from model.networks import AtlasNetDecoder, OctreeDecoder
from model.octree.patches import DEPTH_COLORS, patches_to_mesh
from model.train.images import eval_view
from model.train.tasks import TASKS, encode_with_guide

from .decoding import ATLAS_GRID, decoded_points

TILE = 160
VIEW = dict(azimuth_deg=35.0, elevation_deg=25.0, distance=2.6)


def splats(points: np.ndarray, radius: float = 0.008) -> trimesh.Trimesh:
    """A small octahedron per point, so point sets render with the mesh renderer."""
    octa = trimesh.creation.icosphere(subdivisions=0, radius=radius)
    n, v = len(points), len(octa.vertices)
    verts = (points[:, None, :] + octa.vertices[None]).reshape(-1, 3)
    faces = (octa.faces[None] + (np.arange(n) * v)[:, None, None]).reshape(-1, 3)
    return trimesh.Trimesh(verts, faces, process=False)


def tile(mesh: trimesh.Trimesh | None, face_colors: np.ndarray | None = None) -> Image.Image:
    """A white tile with ``mesh`` (cube coordinates, centred at 0.5) at the fixed 3/4 view."""
    if mesh is None or len(mesh.faces) == 0:
        return Image.new("RGB", (TILE, TILE), (255, 255, 255))
    m = trimesh.Trimesh(mesh.vertices - 0.5, mesh.faces, process=False)
    rgba, _ = render(m, size=TILE, supersample=2, color=(0.55, 0.62, 0.75), face_colors=face_colors, **VIEW)
    a = rgba[..., 3:4].astype(np.float64) / 255.0
    return Image.fromarray((rgba[..., :3] * a + 255.0 * (1 - a)).astype(np.uint8))


def depth_colors(mesh: trimesh.Trimesh) -> np.ndarray:
    """Per-face colours in [0, 1] of a patch mesh written with ``color_by_depth``."""
    return np.asarray(mesh.visual.face_colors)[:, :3] / 255.0


def output_mesh(model, latent: torch.Tensor, resolution: int = 64, guide: Guide | None = None,
                scans: list | None = None, empty_bias: dict[int, float] | None = None
                ) -> list[tuple[trimesh.Trimesh, trimesh.Trimesh | None]]:
    """Per shape: the decoded surface as a mesh, and for octree decoders the depth-coloured patches
    (``guide``, ``scans`` and ``empty_bias`` as :func:`research.decoding.decoded_points`')."""
    dec = model.decoder
    if isinstance(dec, AtlasNetDecoder):
        with torch.no_grad():
            pts = dec.grid(latent, ATLAS_GRID).numpy()
        faces = dec.triangles(ATLAS_GRID).numpy()
        return [(trimesh.Trimesh(p, faces, process=False), None) for p in pts]
    out = []
    for pts, tree in decoded_points(model, latent, None, resolution, 0, scans=scans, empty_bias=empty_bias,
                                     guide=guide):
        if tree is not None and isinstance(dec, OctreeDecoder) and dec.has_plane(tree.depth):
            out.append((patches_to_mesh(tree, world=False), patches_to_mesh(tree, color_by_depth=True, world=False)))
        else:
            out.append((splats(pts), None))
    return out


def figure(data: str, runs: list[tuple[str, str]], split: str = "test", shapes: int = 6,
           categories: list[str] | None = None, keep_scan: bool = False) -> Image.Image:
    """The picture described in the module docstring."""
    loaded = [(n, load_model(p)) for n, p in runs]
    models = [(name, run.model, run.config) for name, run in loaded]
    if keep_scan and any(cfg.task != "completion" for _, _, cfg in models):
        raise ValueError("--keep-scan draws completion models")
    first_cfg = dataclasses.replace(models[0][2], data=data)     # the dataset asked for, not the run's
    if len({cfg.task for _, _, cfg in models}) > 1:
        raise ValueError("--runs must all be of one task (all image models, all autoencoders or all completion models)")
    records = TASKS[first_cfg.task].dataset(first_cfg, split, 0)
    chosen, seen = [], set()
    for i, s in enumerate(records.samples):             # one shape per category, in order
        if (categories is None or s.category in categories) and s.category not in seen:
            chosen.append(i)
            seen.add(s.category)
        if len(chosen) == shapes:
            break
    image_input = first_cfg.task == "image"
    scan_input = first_cfg.task == "completion"
    heads = ((["input"] if image_input else ["partial scan"] if scan_input else []) + ["truth"]
             + [n for n, _, _ in models] + [f"{models[0][0]} by depth"])
    sheet = Image.new("RGB", (TILE * len(heads), 18 + TILE * len(chosen)), (255, 255, 255))
    draw = ImageDraw.Draw(sheet)
    for c, h in enumerate(heads):
        draw.text((c * TILE + 4, 3), h, fill=(0, 0, 0))
    idx = np.array(chosen)
    columns = []
    scans = [records.scan(i) for i in idx] if keep_scan else None
    for (name, model, cfg), (_, run) in zip(models, loaded):
        with torch.no_grad():
            latent, guide = encode_with_guide(model, cfg, records, idx)
        bias = empty_bias_of(run.meta.get("keep_scan")) if keep_scan else None
        columns.append(output_mesh(model, latent, guide=guide, scans=scans, empty_bias=bias))
    for r, i in enumerate(chosen):
        s = records.samples[i]
        tiles = []
        if image_input:
            view = s.images[eval_view(s.shape_id, len(s.images))]
            a = view[..., 3:4].astype(np.float64) / 255.0
            tiles.append(Image.fromarray((view[..., :3] * a + 255 * (1 - a)).astype(np.uint8)).resize((TILE, TILE)))
        if scan_input:                  # the partial scan in the scan frame's cube, as the model saw it
            cube = s.octree.normalizations[0].to_cube(s.truth_frame.to_world(s.partial))
            tiles.append(tile(splats(cube[:: max(1, len(cube) // 2500)], radius=0.006)))
        tiles.append(tile(patches_to_mesh(s.octree, world=False)))
        tiles += [tile(col[r][0]) for col in columns]
        coloured = columns[0][r][1]
        tiles.append(tile(coloured, depth_colors(coloured)) if coloured is not None else tile(None))
        for c, t in enumerate(tiles):
            sheet.paste(t, (c * TILE, 18 + r * TILE))
        draw.text((4, 18 + r * TILE + TILE - 14), s.category, fill=(90, 90, 90))
    legend_x = TILE * (len(heads) - 1) + 4
    for k, d in enumerate(range(2, first_cfg.depth + 1)):
        draw.rectangle([legend_x + 22 * k, 22, legend_x + 22 * k + 8, 30], fill=tuple(int(v) for v in DEPTH_COLORS[d]))
        draw.text((legend_x + 22 * k + 10, 21), str(d), fill=(0, 0, 0))
    return sheet


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.figures", __doc__, [
        "python -m research.figures --data data/procedural --runs aocnn=runs/img psg=runs/img-psg --out fig.png"])
    ap.add_argument("--data", required=True, help="dataset folder the runs were trained on")
    ap.add_argument("--runs", nargs="+", required=True, help="NAME=RUN_FOLDER, the first one is coloured by depth")
    ap.add_argument("--out", required=True, help="PNG to write")
    ap.add_argument("--split", default="test", choices=("train", "val", "test"), help="split to draw from (default test)")
    ap.add_argument("--shapes", type=int, default=6, help="rows: shapes of different categories (default 6)")
    ap.add_argument("--categories", nargs="+", default=None, help="draw shapes of these categories only")
    ap.add_argument("--keep-scan", action="store_true",
                    help="completion: draw the outputs the service sends by default (the scan kept where it "
                         "has points, each run's recorded empty bias)")
    args = ap.parse_args(argv)
    try:
        runs = [tuple(r.split("=", 1)) for r in args.runs]
        if any(len(r) != 2 for r in runs):
            raise ValueError("--runs takes NAME=RUN_FOLDER items")
        img = figure(args.data, runs, args.split, args.shapes, args.categories, args.keep_scan)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    img.save(args.out, optimize=True)
    print(args.out)
    return 0


if __name__ == "__main__":
    sys.exit(main())
