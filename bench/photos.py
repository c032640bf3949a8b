"""Photos in the wild: the image request's time with background removal against without, and real
meshes the model never saw, photographed, reconstructed and recognised.

Time: the photo-like test views of ``--data`` (renders on held-out backgrounds, no alpha, sent as
JPEG) through the service's whole path (decode the upload, the mask, the crop, the encoder, the
decoder, the patch mesh and its GLB): with ``remove_background=auto`` (the bundle's foreground
network) against ``false`` (no mask: the path before the network existed), the same photos, the
same bundle, in the same run; medians over ``--repeats`` passes after a warm-up, and their ratio.

Phone photos (``--phone N``): N test views made 4000 x 3000 JPEGs, through the same path with
``remove_background=auto``, worked on at the working size against at full size, in the same run.

Real meshes (``--meshes``: a folder holding the research meshes named below; skipped when absent):
each rendered from ``--views`` viewpoints, composited as a photo on the held-out backgrounds,
reconstructed through the same path, and the output classified by the classification bundle
(``--classifier``; its 12-rotation vote, the service's ``vote=true``): a reconstruction counts as
its category when the classifier, which never saw the photo, names that category.  Each photo is
also sent with a box prompt (the object's box as a user drags it, :func:`box_prompt`) and with
its exact mask as alpha (what a perfect foreground network would give).

    python -m bench.photos --bundle models/bundles/image-to-shape --data data/procedural
        [--meshes ../shared/meshes] [--classifier models/bundles/classify] [--figure photos.png] [--phone 8]
"""

from __future__ import annotations

import io
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh
from PIL import Image

from model.cli import command_parser
from model.data.photos import box_prompt, with_alpha
from model.image.decode import WORK_SIDE_DEFAULT
from model.image.frame import region_of
from model.image.mask import mask_iou

REAL_MESHES = {
    # file: (category, up axis of the file): ModelNet40 is z-up, ShapeNet y-up
    "mn40_airplane_0003.off": ("airplane", "z"),
    "mn40_chair_0001.off": ("chair", "z"),
    "mn40_chair_0002.off": ("chair", "z"),
}


@dataclass
class Reconstruction:
    """One photo through the service's path: what was done and the decoded octree."""

    framed: object
    octree: object
    glb: bytes
    seconds: dict


def reconstruct(data: bytes, runtime, remove_background: str = "auto",
                work_side: int | None = WORK_SIDE_DEFAULT, box: tuple[int, int, int, int] | None = None
                ) -> Reconstruction:
    """The image endpoint's work on an uploaded photo (bytes), stage by stage, timed; ``work_side``
    as :func:`model.image.decode.decode_photo` (None: the photo at full size, as before it existed);
    ``box``: the user's box prompt, left, top, right, bottom in the upload's pixels (the service's
    ``box=``)."""
    from model.decode import DECODED_NORMALIZATION
    from model.image.decode import decode_photo
    from model.image.mask import MaskSpec
    from model.surface import surface_mesh
    from model.train.images import frame_or_whole
    from service.meshes import encode

    spec = runtime.bundle.image_spec()
    t0 = time.perf_counter()
    decoded = decode_photo(data, work_side=work_side)
    rgba = decoded.rgba
    t1 = time.perf_counter()
    segment = runtime.segment if runtime.has_foreground else None
    region = None if box is None else region_of(box, decoded.size, rgba.shape[:2])
    framed = frame_or_whole(rgba, spec, segment, remove_background, runtime.bundle.mask_spec() or MaskSpec(), region)
    t2 = time.perf_counter()
    latent = runtime.encode_image(framed.image[None])
    t3 = time.perf_counter()
    octree = runtime.decode(latent)
    octree.normalizations = [DECODED_NORMALIZATION]
    t4 = time.perf_counter()
    glb = encode(surface_mesh(octree, "patches"), octree, "glb").data
    t5 = time.perf_counter()
    return Reconstruction(framed, octree, glb, {"decode_input": t1 - t0, "mask_and_crop": t2 - t1,
                                                "encoder": t3 - t2, "decoder": t4 - t3, "mesh": t5 - t4})


def jpeg(rgb: np.ndarray, quality: int = 90) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, "JPEG", quality=quality)
    return buf.getvalue()


def png_with_alpha(rgb: np.ndarray, mask: np.ndarray) -> bytes:
    """A PNG of the photo with its exact mask as alpha (:func:`model.data.photos.with_alpha`)."""
    buf = io.BytesIO()
    Image.fromarray(with_alpha(rgb, mask), "RGBA").save(buf, "PNG")
    return buf.getvalue()


def test_rows(data: str, shapes: int) -> list[tuple[dict, np.ndarray]]:
    """(manifest row, renders) of the first ``shapes`` test shapes, spread over the categories."""
    from model.data.dataset import load_record
    from model.train.data import manifest_rows

    _, rows = manifest_rows(Path(data), "test")
    rows = sorted(rows, key=lambda r: (rows.index(r) % 10, r["category"]))[:shapes]
    return [(r, load_record(Path(data) / r["path"])["images"]) for r in rows]


def test_photos(data: str, shapes: int) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(category, shape id, photo RGB, exact mask) of the first ``shapes`` test shapes, spread over
    the categories, on their photo-like test views."""
    from model.data.photos import photo_split_view

    out = []
    for r, images in test_rows(data, shapes):
        photo = photo_split_view(images, r["shape_id"])
        out.append((r["category"], r["shape_id"], photo.rgb, photo.mask))
    return out


def time_requests(runtime, photos: list[bytes], repeats: int, remove_background: str = "auto",
                  work_side: int | None = WORK_SIDE_DEFAULT) -> tuple[dict, list[Reconstruction]]:
    """Median seconds per request (``total``) and per stage over ``repeats`` passes over ``photos``
    after a warm-up, and the first pass's reconstructions."""
    for data in photos[:2]:
        reconstruct(data, runtime, remove_background, work_side)          # warm-up
    totals, stages, first = [], {}, []
    for i in range(repeats):
        for data in photos:
            r = reconstruct(data, runtime, remove_background, work_side)
            totals.append(sum(r.seconds.values()))
            for k, v in r.seconds.items():
                stages.setdefault(k, []).append(v)
            if i == 0:
                first.append(r)
    return {"total": float(np.median(totals)), **{k: float(np.median(v)) for k, v in stages.items()}}, first


def timing(runtime, photos: list[bytes], repeats: int) -> dict:
    """Median seconds per request and per stage, with and without background removal."""
    return {mode: time_requests(runtime, photos, repeats, mode)[0] for mode in ("false", "auto")}


PHONE_SHORT_SIDE = 3000
"""The short side of a 12-megapixel phone photo (4000 x 3000)."""


def phone_photos(data: str, shapes: int) -> list[tuple[bytes, np.ndarray]]:
    """The first ``shapes`` test shapes' photo-like views made as a phone takes them: 4000 x 3000
    JPEG (quality 90), the object 30-95% of the short side, on the held-out backgrounds; with the
    exact mask (bool)."""
    import dataclasses

    from model.data.photos import TEST_STYLE, photo_composite
    from model.data.shapes import stable_hash

    style = dataclasses.replace(TEST_STYLE, short_side=(PHONE_SHORT_SIDE, PHONE_SHORT_SIDE), aspect=(4 / 3, 4 / 3))
    out = []
    for r, images in test_rows(data, shapes):
        rng = np.random.default_rng(stable_hash("phone-photo", r["shape_id"]))
        photo = photo_composite(images[int(rng.integers(len(images)))], rng, "test", style)
        out.append((jpeg(photo.rgb), photo.mask > 0.5))
    return out


def phone_timing(runtime, photos: list[tuple[bytes, np.ndarray]], repeats: int) -> dict:
    """Median seconds per request of phone photos with background removal, and the mean mask IoU
    at the photo's size: worked on at the working size (:data:`model.image.decode.WORK_SIDE_DEFAULT`)
    against at full size (the path before the working size existed)."""
    import dataclasses

    from model.image.frame import upload_mask

    out = {}
    for name, side in (("full size", None), ("working size", WORK_SIDE_DEFAULT)):
        times, first = time_requests(runtime, [data for data, _ in photos], repeats, "auto", side)
        ious = []
        for r, (_, truth) in zip(first, photos):
            mask = upload_mask(dataclasses.replace(r.framed, size=truth.shape))
            ious.append(mask_iou(mask > 127, truth) if mask is not None else 0.0)
        out[name] = {**times, "mask_iou": float(np.mean(ious))}
    return out


def real_meshes(folder: Path) -> list[tuple[str, str, trimesh.Trimesh]]:
    """(file name, category, mesh) of each of :data:`REAL_MESHES` found in ``folder``, the mesh
    turned y-up, centred, its longest bounding-box edge 1 (the generators' convention)."""
    from model.data.layouts import y_up

    out = []
    for name, (category, up) in REAL_MESHES.items():
        path = folder / name
        if not path.is_file():
            continue
        mesh = y_up(trimesh.load(path, force="mesh", process=False), up)     # the renders' convention
        v = mesh.vertices - (mesh.vertices.max(0) + mesh.vertices.min(0)) / 2
        out.append((name, category, trimesh.Trimesh(v / np.ptp(v, axis=0).max(), mesh.faces, process=False)))
    return out


def real_mesh_photos(folder: Path, views: int) -> list[tuple[str, str, np.ndarray, np.ndarray]]:
    """(category, mesh name, photo RGB, exact mask) of each known real mesh in ``folder`` from
    ``views`` viewpoints, composited on the held-out backgrounds as the photo-like test split is
    (:data:`model.data.photos.TEST_STYLE`), with fixed seeds."""
    from model.data.photos import TEST_STYLE, photo_composite
    from model.data.render import render

    out = []
    for name, category, mesh in real_meshes(folder):
        rng = np.random.default_rng(sum(map(ord, name)))
        for k in range(views):
            rgba, _ = render(mesh, float(rng.uniform(0, 360)), float(rng.uniform(20, 30)), 2.8, size=137,
                             color=tuple(0.45 + 0.4 * rng.random(3)))
            photo = photo_composite(rgba, rng, "test", TEST_STYLE)
            out.append((category, f"{name}#{k}", photo.rgb, photo.mask))
    return out


def classify_output(classifier, octree, depth: int) -> tuple[str, float]:
    """The classification bundle's voted answer (12 rotations about y) for a decoded octree's
    patches, sampled as an oriented point cloud and normalised as an uploaded shape is."""
    from model.octree import PointCloud, build_octree
    from model.octree.batch import merge_octrees
    from model.octree.geometry import up_rotations
    from model.surface import surface_mesh

    m = surface_mesh(octree, "patches", world=False)
    mesh = trimesh.Trimesh(m.vertices, m.faces, process=False)
    pts, face = trimesh.sample.sample_surface(mesh, 20_000, seed=0)
    normals = mesh.face_normals[face]
    o = classifier.bundle.octree
    cloud = PointCloud(pts, normals)
    trees = [build_octree(cloud.rotated(r), o.depth, adaptive=o.adaptive,
                          full_depth=o.full_depth, adaptive_depth=o.adaptive_depth)
             for r in up_rotations("y")]
    probs = classifier.classify(classifier.encode_octree(merge_octrees(trees))).mean(0)
    best = int(np.argmax(probs))
    return classifier.bundle.categories[best], float(probs[best])


def figure(rows: list[tuple[str, np.ndarray, object, object]], path: str) -> None:
    """One row per photo: the photo, the mask used, the encoder's input (the crop) and the output's
    patches, each a tile."""
    from model.octree.patches import patches_to_mesh
    from research.figures import TILE, tile

    def fit(img: Image.Image) -> Image.Image:
        img = img.copy()
        img.thumbnail((TILE, TILE))
        canvas = Image.new("RGB", (TILE, TILE), (255, 255, 255))
        canvas.paste(img, ((TILE - img.width) // 2, (TILE - img.height) // 2))
        return canvas

    sheet = Image.new("RGB", (4 * TILE, len(rows) * TILE), (255, 255, 255))
    for i, (_, rgb, framed, octree) in enumerate(rows):
        crop = np.clip((framed.image.transpose(1, 2, 0) * 0.25 + 0.5) * 255, 0, 255).astype(np.uint8)
        mask = framed.mask if framed.mask is not None else np.zeros(rgb.shape[:2], np.uint8)
        tiles = [fit(Image.fromarray(rgb)), fit(Image.fromarray(mask).convert("RGB")), fit(Image.fromarray(crop)),
                 tile(patches_to_mesh(octree, world=False))]
        for j, t in enumerate(tiles):
            sheet.paste(t, (j * TILE, i * TILE))
    sheet.save(path)


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.photos", __doc__, [
        "python -m bench.photos --bundle models/bundles/image-to-shape --data data/procedural --meshes ../shared/meshes"])
    ap.add_argument("--bundle", default="models/bundles/image-to-shape", help="an image bundle with a foreground network")
    ap.add_argument("--data", default="data/procedural", help="a built dataset (its test split's photo-like views)")
    ap.add_argument("--shapes", type=int, default=26, help="test photos timed (default 26)")
    ap.add_argument("--repeats", type=int, default=3, help="passes over the photos per mode (default 3)")
    ap.add_argument("--threads", type=int, default=2, help="onnxruntime threads (default 2)")
    ap.add_argument("--meshes", default=None, help="a folder with the real meshes (see REAL_MESHES)")
    ap.add_argument("--views", type=int, default=3, help="photos per real mesh (default 3)")
    ap.add_argument("--classifier", default="models/bundles/classify", help="the classification bundle")
    ap.add_argument("--figure", default=None, help="write photo | mask | crop | output rows to this PNG")
    ap.add_argument("--phone", type=int, default=0,
                    help="also time this many test views as 12-megapixel phone photos, at the working size "
                         "against at full size (default 0: not timed)")
    args = ap.parse_args(argv)
    from export.bundle import BundleError, load_bundle
    from export.runtime import Runtime

    try:
        runtime = Runtime(load_bundle(args.bundle), threads=args.threads, spinning=False)   # as the service
        photos = test_photos(args.data, args.shapes)
    except (BundleError, FileNotFoundError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if not runtime.has_foreground:
        print(f"error: {args.bundle} has no foreground network", file=sys.stderr)
        return 2
    t = timing(runtime, [jpeg(p[2]) for p in photos], args.repeats)
    print(f"{len(photos)} photo-like test views, {args.repeats} passes, {args.threads} threads; median ms per request")
    print("| stage | remove_background=false | auto |")
    print("|---|---|---|")
    for k in t["auto"]:
        print(f"| {k} | {1e3 * t['false'][k]:.1f} | {1e3 * t['auto'][k]:.1f} |")
    print(f"ratio auto / false: {t['auto']['total'] / t['false']['total']:.2f}x")
    if args.phone:
        p = phone_timing(runtime, phone_photos(args.data, args.phone), args.repeats)
        print(f"\n{args.phone} test views as 4000 x 3000 JPEG phone photos, remove_background=auto, "
              f"{args.repeats} passes; median ms per request")
        print("| stage | full size | working size |\n|---|---|---|")
        for k in p["working size"]:
            if k != "mask_iou":
                print(f"| {k} | {1e3 * p['full size'][k]:.1f} | {1e3 * p['working size'][k]:.1f} |")
        print(f"ratio full / working size: {p['full size']['total'] / p['working size']['total']:.2f}x; "
              f"mask IoU at the photo's size: {p['full size']['mask_iou']:.3f} full, "
              f"{p['working size']['mask_iou']:.3f} working size")
    shown = [(c, rgb, reconstruct(jpeg(rgb), runtime).framed, None) for c, _, rgb, _ in photos[:4]]
    if args.meshes and Path(args.meshes).is_dir():
        classifier = Runtime(load_bundle(args.classifier), threads=args.threads)
        real = real_mesh_photos(Path(args.meshes), args.views)
        print("\n| real mesh, view | category | mask IoU | classified as (voted probability) "
              "| with a box prompt: mask IoU | classified as | with the exact mask: classified as |")
        print("|---|---|---|---|---|---|---|")
        hits = {"photo": 0, "box prompt": 0, "exact mask": 0}
        for category, name, rgb, truth in real:
            cells = []
            for way, r in (("photo", reconstruct(jpeg(rgb), runtime)),
                           ("box prompt", reconstruct(jpeg(rgb), runtime, box=box_prompt(truth))),
                           ("exact mask", reconstruct(png_with_alpha(rgb, truth), runtime))):
                if way != "exact mask":
                    ours = r.framed.mask > 127 if r.framed.mask is not None else np.zeros(truth.shape, bool)
                    cells.append(f"{mask_iou(ours, truth > 0.5):.3f}")
                label, p = classify_output(classifier, r.octree, classifier.bundle.octree.depth)
                hits[way] += label == category
                cells.append(f"{label} ({p:.2f})")
                if way == "photo":
                    shown.append((category, rgb, r.framed, r.octree))
            print(f"| {name} | {category} | " + " | ".join(cells) + " |")
        said = {"photo": "through the masks", "box prompt": "with a box prompt", "exact mask": "with the exact mask"}
        print(f"recognised as their category (of {len(real)}): "
              + "; ".join(f"{n} {said[way]}" for way, n in hits.items()))
    if args.figure:
        rows = []
        for c, rgb, framed, octree in shown:
            octree = octree or reconstruct(jpeg(rgb), runtime).octree
            rows.append((c, rgb, framed, octree))
        figure(rows, args.figure)
        print(f"figure: {args.figure}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
