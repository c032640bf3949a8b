"""Closed-surface extraction speed: :func:`model.surface.watertight_mesh` against depth and leaf
count, beside the same surface before its vertices are merged leaf by leaf (``merge=False``: the
finest grid's contour) and scikit-image's ``marching_cubes`` on the dense grid of the same
resolution.

For each input octree, the extraction runs ``--repeats`` times after one warm-up (one thread for
NumPy's BLAS: the service's inference threads run beside it); the table gives the median and
the worst.  The reference is ``skimage.measure.marching_cubes`` (Lewiner) on the full (2^D + 1)^3
grid of the unit cube, fed the same inside/outside field as floats: what contouring the dense
grid costs by itself, before any field is computed.  Inputs: the test meshes' octrees (the
generated ones of ``tests/meshes.py``, and the research meshes of ``--mesh-dir`` where present),
built from virtual scans as the dataset does, and the shipped image model's outputs on
``--data``'s test split where that dataset exists.

    python -m bench.surface [--depths 6 7 8] [--repeats 5] [--data data/procedural] [--shapes 12]
                            [--figure surfaces.png]

``--figure`` draws, for five decoded shapes and five test meshes at the first depth, the patches
and the closed surface from the front and from behind.  ``--accuracy`` measures instead, for
every test mesh and depth, both surfaces against 200,000 samples of the mesh: the Chamfer
distance (x10^3, cube units), the F-score at 1% of the diagonal and the normal consistency
(the mean |cos| between a point's normal and its nearest neighbour's in the other set, both
ways), each surface drawn uniformly by area (100,000 points), and the share of the mesh's area
lying in parts thinner than a cell (both faces within a cell of each other); the Chamfer
distance of the closed surface before its vertices are merged; and the same for the other
approach compared, marching cubes on the signed field (:func:`marching_cubes_surface`).

"closed (welded)" is :func:`model.surface.checks.is_closed_embedded`: closed and 2-manifold as a
reader that merges vertices by position loads the mesh.  "crossing faces": faces that cross
another face (:func:`model.surface.crossing.crossing_faces`, MeshLab's rule in double precision).
"""

from __future__ import annotations

import os
import sys
import time
from pathlib import Path

import numpy as np

from model.cli import command_parser

REPO = Path(__file__).resolve().parents[1]


def timed(fn, repeats: int) -> tuple[float, float, object]:
    """(median seconds, worst seconds, last result) of ``repeats`` calls after a warm-up."""
    out = fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t)
    return float(np.median(times)), float(max(times)), out


def dense_reference(octree) -> float:
    """Seconds of skimage's marching cubes on the dense (2^D + 3)^3 corner grid of the same
    inside/outside field (padded so that the surface closes)."""
    from skimage.measure import marching_cubes

    from model.surface import signed_grid
    from model.surface.grid import PAD

    grid, _, inside = signed_grid(octree)
    n = 1 << octree.depth
    field = np.zeros((n + 2 * PAD + 1,) * 3, np.float32)          # the whole cube, padded as the grid is
    lo = grid.origin + PAD
    sx, sy, sz = inside.shape
    field[lo[0]:lo[0] + sx, lo[1]:lo[1] + sy, lo[2]:lo[2] + sz] = inside
    t = time.perf_counter()
    marching_cubes(field, 0.5, method="lewiner")
    return time.perf_counter() - t


def marching_cubes_surface(octree) -> tuple[np.ndarray, np.ndarray]:
    """The other approach the closed surface was compared with: the same inside/outside corners
    made a signed distance (the planes' mean value near them, clamped to a cell; a cell elsewhere)
    and meshed by skimage's marching cubes.  (vertices in cube coordinates, faces)."""
    from skimage.measure import marching_cubes

    from model.surface import signed_grid

    grid, _, inside = signed_grid(octree)
    h = grid.h
    size = np.where(grid.near, np.clip(np.abs(grid.value), 1e-3 * h, h), h)
    verts, faces, _, _ = marching_cubes(np.where(inside, -size, size), 0.0, method="lewiner")
    return (verts + grid.origin) * h, faces


def scanned_octrees(depths: list[int], mesh_dir: str) -> list[tuple[str, object]]:
    import trimesh

    from model.data.scanner import scan
    from model.octree import build_octree

    sys.path.insert(0, str(REPO))
    from tests.meshes import GENERATED, mesh_path

    names = list(GENERATED) + (sorted(os.listdir(mesh_dir)) if os.path.isdir(mesh_dir) else [])
    out = []
    for name in names:
        if not name.endswith((".obj", ".off", ".stl", ".ply")):
            continue
        path = mesh_path(name) if name in GENERATED else os.path.join(mesh_dir, name)
        pts, nrm = scan(trimesh.load(path, force="mesh"), resolution=256)
        for depth in depths:
            out.append((f"{name} d{depth}", build_octree((pts.astype(float), nrm.astype(float)), depth, neighbors=False)))
    return out


def decoded_octrees(data: str, shapes: int) -> list[tuple[str, object]]:
    """The shipped image model's outputs for the first render of test shapes (one per category in turn)."""
    import json

    from export.bundle import load_bundle
    from export.runtime import Runtime
    from model.data.dataset import load_record
    from model.image.frame import prepare_image
    from model.octree.batch import split_octree

    manifest = Path(data) / "manifest.json"
    if not manifest.is_file():
        return []
    runtime = Runtime(load_bundle(REPO / "models" / "bundles" / "image-to-shape"), threads=1)
    rows = [r for r in json.loads(manifest.read_text())["records"] if r["split"] == "test"]
    step = max(1, len(rows) // shapes)
    out = []
    for r in rows[::step][:shapes]:
        image = prepare_image(load_record(Path(data) / r["path"])["images"][0], runtime.bundle.image_spec())
        tree = split_octree(runtime.decode(runtime.encode_image(image[None])), neighbors=False)[0]
        out.append((f"decoded {r['category']}", tree))
    return out


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.surface", __doc__, [
        "python -m bench.surface --depths 6 7 --repeats 5",
        "python -m bench.surface --depths 6 --data data/procedural --shapes 26"])
    ap.add_argument("--depths", type=int, nargs="+", default=[6, 7, 8], help="octree depths of the meshes (default 6 7 8)")
    ap.add_argument("--repeats", type=int, default=5, help="timed runs per input after a warm-up (default 5)")
    ap.add_argument("--mesh-dir", default=str(REPO.parent / "shared" / "meshes"),
                    help="more real meshes, where present (default: ../shared/meshes beside the checkout)")
    ap.add_argument("--data", default="data/procedural",
                    help="a dataset whose test renders go through the shipped image model (default data/procedural)")
    ap.add_argument("--shapes", type=int, default=12, help="decoded shapes (default 12)")
    ap.add_argument("--figure", default=None, help="also draw the inputs' surfaces into this PNG (default: none)")
    ap.add_argument("--accuracy", action="store_true", help="measure both surfaces against the test meshes instead")
    args = ap.parse_args(argv)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from model.octree.patches import patch_mesh
    from model.surface import watertight_mesh
    from model.surface.crossing import crossing_faces

    if args.accuracy:
        return accuracy(args.depths, args.mesh_dir)
    inputs = decoded_octrees(args.data, args.shapes) + scanned_octrees(args.depths, args.mesh_dir)
    print("| input | leaves | patch faces | closed faces | ratio | unmerged faces | closed (welded) "
          "| crossing faces | median ms | worst ms | unmerged median ms | dense MC ms | worst / dense |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, tree in inputs:
        med, worst, m = timed(lambda: watertight_mesh(tree, world=False), args.repeats)
        fine_med, _, fine = timed(lambda: watertight_mesh(tree, world=False, merge=False), args.repeats)
        patches = len(patch_mesh(tree, world=False).faces)
        dense = dense_reference(tree)
        print(f"| {name} | {sum(tree.leaves_per_depth())} | {patches} | {len(m.faces)} | {len(m.faces) / max(patches, 1):.1f} "
              f"| {len(fine.faces)} | {'yes' if m.closed else 'NO'} | {crossing_faces(m.vertices, m.faces).sum()} "
              f"| {med * 1e3:.1f} | {worst * 1e3:.1f} | {fine_med * 1e3:.1f} | {dense * 1e3:.1f} | {worst / dense:.2f} |",
              flush=True)
    if args.figure:
        decoded = [x for x in inputs if x[0].startswith("decoded")]
        meshes = [x for x in inputs if x[0].endswith(f"d{args.depths[0]}")]
        figure(decoded[::max(1, len(decoded) // 5)][:5] + meshes[:5], args.figure)
    return 0


def accuracy(depths: list[int], mesh_dir: str) -> int:
    """The ``--accuracy`` table (module docstring)."""
    import trimesh

    from model.octree.metrics import Reference
    from model.surface import surface_mesh, watertight_mesh
    from model.surface.checks import is_closed
    from research.measures import fscore_threshold

    print("| mesh | depth | thin share | patches CD | closed CD | ratio | unmerged CD | MC CD | MC ratio "
          "| F: patches / closed / MC | normals: patches / closed / MC | closed: ours / MC |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, tree in scanned_octrees(depths, mesh_dir):
        mesh_name, depth = name.rsplit(" d", 1)
        path = mesh_path_of(mesh_name, mesh_dir)
        mesh = trimesh.load(path, force="mesh")
        truth_pts, fid = trimesh.sample.sample_surface(mesh, 200_000, seed=0)
        truth = tree.normalizations[0].to_cube(truth_pts)
        h = 1.0 / (1 << tree.depth)
        # thin: a sample whose face's opposite side (along its normal, inward) is within a cell
        normals = mesh.face_normals[fid]
        hits = mesh.ray.intersects_location(truth_pts - normals * 1e-6 * mesh.scale, -normals, multiple_hits=False)
        depth_to = np.full(len(truth_pts), np.inf)
        depth_to[hits[1]] = np.linalg.norm(hits[0] - truth_pts[hits[1]], axis=1)
        thin = float(np.mean(depth_to / tree.normalizations[0].scale < h))
        threshold, reference = fscore_threshold(truth), Reference(truth)
        meshes = [surface_mesh(tree, kind, world=False) for kind in ("patches", "watertight")]
        unmerged = watertight_mesh(tree, world=False, merge=False)
        mc_verts, mc_faces = marching_cubes_surface(tree)
        cd, f, nc = [], [], []
        for verts, faces in [(m.vertices, m.faces) for m in meshes] + [(mc_verts, mc_faces)] + \
                [(unmerged.vertices, unmerged.faces)]:
            surface = trimesh.Trimesh(verts, faces, process=False)
            pts, pid = trimesh.sample.sample_surface(surface, 100_000, seed=1)
            near = reference.nearest(pts)
            cd.append(near.chamfer() * 1e3)
            f.append(near.fscore(threshold))
            # normal consistency: |cos| between each point's normal and its nearest neighbour's, both ways
            to_truth = np.abs(np.einsum("ij,ij->i", surface.face_normals[pid], normals[near.from_index]))
            to_pred = np.abs(np.einsum("ij,ij->i", normals, surface.face_normals[pid][near.to_index]))
            nc.append((to_truth.mean() + to_pred.mean()) / 2)
        yes = {True: "yes", False: "NO"}
        print(f"| {mesh_name} | {depth} | {thin:.0%} | {cd[0]:.4f} | {cd[1]:.4f} | {cd[1] / cd[0]:.2f} | {cd[3]:.4f} "
              f"| {cd[2]:.4f} | {cd[2] / cd[0]:.2f} | {f[0]:.3f} / {f[1]:.3f} / {f[2]:.3f} "
              f"| {nc[0]:.3f} / {nc[1]:.3f} / {nc[2]:.3f} | {yes[meshes[1].closed]} / {yes[is_closed(mc_faces)]} |", flush=True)
    return 0


def mesh_path_of(name: str, mesh_dir: str) -> str:
    sys.path.insert(0, str(REPO))
    from tests.meshes import GENERATED, mesh_path

    return mesh_path(name) if name in GENERATED else os.path.join(mesh_dir, name)


def figure(inputs: list[tuple[str, object]], out: str) -> None:
    """One row per input: patches, closed surface, closed surface seen from behind; its name."""
    import trimesh
    from PIL import Image, ImageDraw

    from model.surface import surface_mesh
    from research.figures import TILE, VIEW, tile

    rows = []
    for name, tree in inputs:
        tiles = []
        for kind, azimuth in (("patches", VIEW["azimuth_deg"]), ("watertight", VIEW["azimuth_deg"]),
                              ("watertight", VIEW["azimuth_deg"] + 180)):
            m = surface_mesh(tree, kind, world=False)
            mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
            if azimuth != VIEW["azimuth_deg"]:
                mesh.apply_transform(trimesh.transformations.rotation_matrix(np.pi, (0, 1, 0), (0.5, 0.5, 0.5)))
            tiles.append(tile(mesh))
        row = Image.new("RGB", (3 * TILE, TILE + 16), (255, 255, 255))
        for i, t in enumerate(tiles):
            row.paste(t, (i * TILE, 16))
        ImageDraw.Draw(row).text((4, 2), f"{name}: patches | closed | closed, behind", fill=(0, 0, 0))
        rows.append(row)
    sheet = Image.new("RGB", (3 * TILE, sum(r.height for r in rows)), (255, 255, 255))
    y = 0
    for r in rows:
        sheet.paste(r, (0, y))
        y += r.height
    sheet.save(out)


if __name__ == "__main__":
    sys.exit(main())
