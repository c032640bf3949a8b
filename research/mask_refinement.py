"""The object's mask in photos, three ways, on the same validation photos: the served first look
alone, the first look refined by a colour model (OpenCV's GrabCut, seeded by it), and the first
look refined by the refinement network (a second look at the object's resolution).

    python -m research.mask_refinement --data DATA [--refine RUN_OR_CHECKPOINT] [--bundle B]
        [--limit N] [--grabcut] [--out results.json]

The photos are the refinement network's validation composites (:func:`model.train.foreground.
refine_batch`'s, one per validation shape of DATA, rendered at DATA's render size), whole: each
method works at the photo's resolution, as the service does.  Reported per method: the mask IoU
(category mean and overall), the thin parts' recall (:func:`model.train.foreground.thin_parts`:
the object's pixels within 2% of its box's longest side from the background, the share the mask
keeps), the share of photos where the object is lost, and the time per photo (median).
"""

from __future__ import annotations

import statistics
import sys
import time
from collections.abc import Callable

import numpy as np
import torch

from export.bundle import load_bundle
from export.exporter import load_refine
from export.runtime import Runtime
from model.cli import command_parser
from model.data.photos import Photo, photo_composite
from model.data.shapes import stable_hash
from model.files import json_text, write_atomic
from model.image.mask import MaskSpec, NoObjectError, mask_bounds, mask_iou, object_mask, object_square, resize_mask
from model.train.data import RecordSet
from model.train.foreground import REFINE_STYLE

from .masks import thin_recall
from .results import category_means


def validation_photos(data: str, limit: int | None = None) -> list[tuple[str, Photo]]:
    """(category, photo) of each validation shape: the refinement's validation composite."""
    records = RecordSet(data, "val", None, depth=None, limit=limit, images=True)
    out = []
    for s in records.samples:
        rng = np.random.default_rng(stable_hash("refine-val", s.shape_id))
        out.append((s.category, photo_composite(s.images[int(rng.integers(len(s.images)))], rng, "train", REFINE_STYLE)))
    return out


def refine_in_torch(path: str) -> Callable[[np.ndarray], np.ndarray]:
    """A refinement network (run or checkpoint) in torch: a (4, S, S) crop input to its object
    probability (S, S)."""
    loaded = load_refine(path)
    net = loaded.model.net.eval()

    def refine(x: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return torch.sigmoid(net(torch.from_numpy(x[None]))).numpy()[0, 0]
    refine.size = loaded.config.image_size
    return refine


def grabcut(rgb: np.ndarray, first: np.ndarray, spec: MaskSpec, side: int = 256, iterations: int = 3) -> np.ndarray:
    """The first mask refined by OpenCV's GrabCut in the object's square (its longest side brought
    to ``side`` pixels): sure object where the first mask is above 0.95 (eroded), probable object
    above 0.5, probable background within the square, sure background at its border."""
    import cv2  # deferred: OpenCV is measured here, not a dependency

    h, w = first.shape
    y0, y1, x0, x1 = object_square(mask_bounds(first > 0.5), h, w, spec.crop_margin)
    f = side / max(y1 - y0, x1 - x0)
    sh, sw = max(2, round((y1 - y0) * f)), max(2, round((x1 - x0) * f))
    crop = cv2.resize(np.ascontiguousarray(rgb[y0:y1, x0:x1]), (sw, sh), interpolation=cv2.INTER_AREA)
    p = cv2.resize(np.ascontiguousarray(first[y0:y1, x0:x1]), (sw, sh), interpolation=cv2.INTER_LINEAR)
    seed = np.full((sh, sw), cv2.GC_PR_BGD, np.uint8)
    seed[p > 0.5] = cv2.GC_PR_FGD
    seed[cv2.erode((p > 0.95).astype(np.uint8), np.ones((5, 5), np.uint8)) > 0] = cv2.GC_FGD
    seed[[0, -1], :] = seed[:, [0, -1]] = cv2.GC_BGD
    if not (seed == cv2.GC_FGD).any() and not (seed == cv2.GC_PR_FGD).any():
        return first
    bgd, fgd = np.zeros((1, 65), np.float64), np.zeros((1, 65), np.float64)
    cv2.grabCut(cv2.cvtColor(crop, cv2.COLOR_RGB2BGR), seed, None, bgd, fgd, iterations, cv2.GC_INIT_WITH_MASK)
    fg = np.isin(seed, (cv2.GC_FGD, cv2.GC_PR_FGD)).astype(np.float32)
    out = np.zeros_like(first)
    out[y0:y1, x0:x1] = resize_mask(fg, y1 - y0, x1 - x0)
    return out


def measure(photos: list[tuple[str, Photo]], method: Callable[[np.ndarray], np.ndarray]) -> dict:
    """IoU, thin-part recall, losses and time of ``method`` (rgb -> mask) on ``photos``."""
    ious, recalls, lost, seconds, cats = [], [], 0, [], []
    for category, photo in photos:
        truth = photo.mask > 0.5
        t = time.perf_counter()
        try:
            ours = method(photo.rgb) > 0.5
        except NoObjectError:
            ours, lost = np.zeros_like(truth), lost + 1
        seconds.append(time.perf_counter() - t)
        ious.append(mask_iou(ours, truth))
        recalls.append(thin_recall(ours, photo))
        cats.append(category)
    per_cat = category_means(cats, ious)
    return {"photos": len(photos), "mask_iou_category_mean": float(np.mean(list(per_cat.values()))),
            "mask_iou_mean": float(np.mean(ious)), "thin_recall_mean": float(np.mean(recalls)),
            "thin_recall_category_mean": float(np.mean(list(category_means(cats, recalls).values()))),
            "lost": lost, "ms_median": 1e3 * statistics.median(seconds), "mask_iou": per_cat,
            "per_photo": [{"category": c, "iou": i, "thin_recall": r} for c, i, r in zip(cats, ious, recalls)]}


def compare(data: str, bundle: str, refine: str | None, limit: int | None, with_grabcut: bool,
            grabcut_side: int = 256, grabcut_iterations: int = 3) -> dict:
    runtime = Runtime(load_bundle(bundle))
    spec = runtime.bundle.mask_spec()
    photos = validation_photos(data, limit)
    first = lambda rgb: object_mask(rgb, runtime.segment, spec)                     # noqa: E731
    rows = {"first look": measure(photos, first)}
    if with_grabcut:
        rows["first look + GrabCut"] = measure(photos, lambda rgb: grabcut(rgb, first(rgb), spec, grabcut_side,
                                                                          grabcut_iterations))
    if refine is not None:
        net = refine_in_torch(refine)
        crop = MaskSpec(**{**spec.to_dict(), "crop_size": net.size})
        rows["first look + refinement network"] = measure(photos, lambda rgb: object_mask(rgb, runtime.segment, crop,
                                                                                            net))
    return {"data": data, "bundle": bundle, "refine": refine, "methods": rows}


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m research.mask_refinement", __doc__, [
        "python -m research.mask_refinement --data data/fg384 --refine runs/refine256 --grabcut --limit 60"])
    ap.add_argument("--data", required=True, help="a dataset with a val split of renders (e.g. rendered at 384)")
    ap.add_argument("--bundle", default="models/bundles/image-to-shape", help="the image bundle whose foreground "
                    "network gives the first look (default the shipped one)")
    ap.add_argument("--refine", default=None, help="a refinement network's run or checkpoint (python -m model.train refine)")
    ap.add_argument("--grabcut", action="store_true", help="also the GrabCut refinement (needs opencv-python-headless)")
    ap.add_argument("--grabcut-side", type=int, default=256, help="GrabCut's working side in pixels (default 256)")
    ap.add_argument("--grabcut-iterations", type=int, default=3, help="GrabCut's iterations (default 3)")
    ap.add_argument("--limit", type=int, default=None, help="the first N validation shapes only")
    ap.add_argument("--out", default=None, help="write the figures (and per-photo rows) here")
    args = ap.parse_args(argv)
    try:
        res = compare(args.data, args.bundle, args.refine, args.limit, args.grabcut, args.grabcut_side,
                      args.grabcut_iterations)
    except (ValueError, FileNotFoundError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.out:
        write_atomic(args.out, json_text(res).encode())
    print(f"{'method':34s} {'IoU (cat. mean)':>15s} {'IoU':>7s} {'thin recall':>11s} {'lost':>5s} {'ms':>7s}")
    for name, r in res["methods"].items():
        print(f"{name:34s} {r['mask_iou_category_mean']:15.4f} {r['mask_iou_mean']:7.4f} {r['thin_recall_mean']:11.4f} "
              f"{r['lost']:5d} {r['ms_median']:7.1f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
