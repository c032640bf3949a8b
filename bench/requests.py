"""The request path through the running service: latency of one request at a time, and where it
goes (``Server-Timing``), for the inputs of the request-speed targets.

    python -m bench.requests [--requests 12] [--drop 2] [--cases completion photo render]
                             [--query surface=patches] [--against CHECKOUT] [--json PATH]

Starts ``python -m service`` with the bundled models (:func:`bench.load.serve`), sends each case's
request ``--requests`` times in a row, drops the first ``--drop`` (warm-up), and prints the median
and the worst latency measured by the client, each stage's median, and the share of the median
request spent outside the networks (completion: encoder + decoder; photos: mask + encoder +
decoder).  ``--against``: a checkout of another version (a git worktree) serves beside this one,
the requests alternate between the two, and the ratios this / other are printed: both meet the
machine in the same state (a 2-core virtual machine drifts by 20% from one minute to the next).
Cases: ``completion``, the 20,000-point scan examples/car_partial_scan.ply at the
model's depth 7; ``photo``, a 640x480 JPEG photo of a generated chair on a procedural scene
(background removal on); ``photo-kept``, the same photo with ``remove_background=false`` (with
``photo`` also asked for, the two are measured again alternating and their ratio printed, at the
median and at the 90th percentile, with both worst requests);
``render``, examples/chair.png (RGBA); ``scan-200k``, a dense partial scan of 200,000 points (a
generated car seen from 3-5 views with holes and noise, as the dataset's scans, in the scanner's
order; binary PLY without normals), the large end of the request-speed issue's inputs.
"""

from __future__ import annotations

import contextlib
import io
import json
import statistics
import sys
import time
from pathlib import Path

import httpx2 as httpx
import numpy as np
from PIL import Image

from bench.load import _stages, serve
from model.cli import command_parser

NETWORKS = {"completion": ("encoder", "decoder"), "scan-200k": ("encoder", "decoder"),
            "photo": ("mask", "encoder", "decoder"), "photo-kept": ("encoder", "decoder"),
            "render": ("encoder", "decoder")}
CASE_QUERY = {"photo-kept": "remove_background=false"}
"""Query parameters a case adds to ``--query``: ``photo-kept`` is the photo with its background kept."""
RATIOS = (("photo", "photo-kept", 2.0),)
"""(case, reference case, target): a ratio printed when both were measured (the photo issue asks a
photo with background removal for at most twice the request that keeps the background)."""
TARGETS = {"completion": (100.0, 0.30), "photo": (40.0, 0.35)}
"""Case -> (median latency in ms, share outside the networks) the request-speed issue asks for."""


def photo_jpeg(seed: int = 0) -> bytes:
    """A 640x480 JPEG photo of a generated chair (a 384-pixel render) on a procedural scene."""
    from model.data.photos import PhotoStyle, photo_composite
    from model.data.render import render_views
    from model.data.shapes import generate

    rng = np.random.default_rng(seed)
    render = render_views(generate("chair", 3), n_views=1, rng=rng, size=384)[0][0]
    style = PhotoStyle(scale=(0.6, 0.6), short_side=(480, 480), aspect=(4 / 3, 4 / 3), real=0.0, jpeg=0.0)
    photo = photo_composite(render, rng, "train", style)
    buf = io.BytesIO()
    Image.fromarray(photo.rgb).save(buf, format="JPEG", quality=90)
    return buf.getvalue()


def dense_scan_ply(points: int = 200_000, seed: int = 0) -> bytes:
    """A binary PLY (x y z, float32, no normals) of ``points`` points of a partial scan of a
    generated car, scanned finely enough to hold them, kept in the scanner's order."""
    from model.data.partial import partial_scan
    from model.data.shapes import generate

    rng = np.random.default_rng(seed)
    pts, _ = partial_scan(generate("car", 3), rng, resolution=640)
    keep = np.sort(rng.choice(len(pts), points, replace=False))
    header = (f"ply\nformat binary_little_endian 1.0\nelement vertex {points}\n"
              "property float x\nproperty float y\nproperty float z\nend_header\n").encode()
    return header + np.ascontiguousarray(pts[keep], "<f4").tobytes()


def case_upload(case: str) -> tuple[str, str, str, bytes]:
    """(endpoint, field, file name, bytes) of a case."""
    if case == "completion":
        return "complete", "points", "car_partial_scan.ply", Path("examples/car_partial_scan.ply").read_bytes()
    if case == "scan-200k":
        return "complete", "points", "dense_scan.ply", dense_scan_ply()
    if case in ("photo", "photo-kept"):
        return "image-to-shape", "image", "photo.jpg", photo_jpeg()
    return "image-to-shape", "image", "chair.png", Path("examples/chair.png").read_bytes()


def measure(arms: dict[str, tuple[str, str]], requests: int, drop: int, query: str) -> dict[str, dict]:
    """Per arm (label -> (service base URL, case)) the figures of ``requests`` requests, the first
    ``drop`` left out; the arms' requests alternate (the order swapped every round), so that all
    meet the machine in the same state."""
    latency = {k: [] for k in arms}
    stages: dict[str, dict[str, list[float]]] = {k: {} for k in arms}
    uploads = {case: case_upload(case) for _, case in arms.values()}        # made once, not timed
    with httpx.Client(timeout=120) as client:
        for i in range(requests):
            for label in (list(arms) if i % 2 == 0 else list(arms)[::-1]):
                base, case = arms[label]
                endpoint, field, name, data = uploads[case]
                params = "&".join(q for q in (query, CASE_QUERY.get(case, "")) if q)
                t = time.perf_counter()
                r = client.post(f"{base}/v1/{endpoint}" + (f"?{params}" if params else ""), files={field: (name, data)})
                dt = time.perf_counter() - t
                if r.status_code != 200:
                    raise RuntimeError(f"{case} ({label}): {r.status_code} {r.text[:200]}")
                latency[label].append(dt)
                for stage, sec in _stages(r.headers.get("server-timing", "")).items():
                    stages[label].setdefault(stage, []).append(sec)
    return {label: _row(arms[label][1], latency[label][drop:], {k: v[drop:] for k, v in stages[label].items()})
            for label in arms}


def _row(case: str, latency: list[float], stages: dict[str, list[float]]) -> dict:
    median = {k: 1e3 * statistics.median(v) for k, v in stages.items()}
    p50 = 1e3 * statistics.median(latency)
    networks = sum(median.get(s, 0.0) for s in NETWORKS[case])
    return {"case": case, "requests": len(latency), "p50_ms": p50, "p90_ms": 1e3 * float(np.percentile(latency, 90)),
            "worst_ms": 1e3 * max(latency),
            "outside_networks": 1 - networks / p50, "stage_ms": median}


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.requests", __doc__, ["python -m bench.requests --cases completion photo",
                                                              "python -m bench.requests --against ../aocnn-98dd16a"])
    ap.add_argument("--requests", type=int, default=12, help="requests per case (default 12)")
    ap.add_argument("--drop", type=int, default=2, help="first requests left out (default 2; fewer than --requests)")
    ap.add_argument("--cases", nargs="+", choices=sorted(NETWORKS), default=["completion", "photo", "render"],
                    help="the requests measured (default: completion photo render)")
    ap.add_argument("--query", default="", help="query parameters of every request (default: none)")
    ap.add_argument("--against", default=None, help="a checkout of another version (e.g. a git worktree): its "
                    "service runs beside this one, requests alternate, and the ratios are printed")
    ap.add_argument("--json", default=None, help="also write the figures here (per case {this, other}; "
                    "default: none)")
    args = ap.parse_args(argv)
    if not 0 <= args.drop < args.requests:
        print(f"error: --drop must be at least 0 and below --requests ({args.requests}), got {args.drop}", file=sys.stderr)
        return 2
    if args.against and not (Path(args.against) / "service" / "__main__.py").is_file():
        print(f"error: --against {args.against} is not a checkout of this project (no service/__main__.py)",
              file=sys.stderr)
        return 2
    with contextlib.ExitStack() as stack:
        bases = {"this": stack.enter_context(serve())[0]}
        if args.against:
            bases["other"] = stack.enter_context(serve(cwd=args.against))[0]
        rows = [measure({side: (base, c) for side, base in bases.items()}, args.requests, args.drop, args.query)
                for c in args.cases]
        pairs = [(c, ref, target, measure({c: (bases["this"], c), ref: (bases["this"], ref)}, args.requests,
                                          args.drop, args.query))
                 for c, ref, target in RATIOS if c in args.cases and ref in args.cases]
    print(f"{args.requests - args.drop} requests a case (first {args.drop} dropped), one at a time"
          + (f", ?{args.query}" if args.query else "")
          + (f", alternating with {args.against}" if args.against else ""))
    for both in rows:
        for side, r in both.items():
            target = TARGETS.get(r["case"]) if side == "this" else None
            goal = f"  (targets: p50 <= {target[0]:.0f} ms, outside <= {target[1]:.0%})" if target else ""
            label = r["case"] if side == "this" else "(other)"
            print(f"{label:>10}: p50 {r['p50_ms']:6.1f} ms, worst {r['worst_ms']:6.1f} ms, outside the networks "
                  f"{r['outside_networks']:.0%}{goal}")
            print("            median ms per stage: " + ", ".join(f"{k} {v:.1f}" for k, v in r["stage_ms"].items()))
        if "other" in both:
            this, other = both["this"], both["other"]
            ratios = {k: v / other["stage_ms"][k] for k, v in this["stage_ms"].items() if other["stage_ms"].get(k)}
            print(f"            this / other: p50 {this['p50_ms'] / other['p50_ms']:.2f}x, worst "
                  f"{this['worst_ms'] / other['worst_ms']:.2f}x; " + ", ".join(f"{k} {v:.2f}x" for k, v in ratios.items()))
    for case, reference, target, both in pairs:
        a, b = both[case], both[reference]
        print(f"{case} / {reference}, requests alternating: p50 {a['p50_ms']:.1f} / {b['p50_ms']:.1f} ms = "
              f"{a['p50_ms'] / b['p50_ms']:.2f}x, p90 {a['p90_ms'] / b['p90_ms']:.2f}x (worst {a['worst_ms']:.1f} / "
              f"{b['worst_ms']:.1f} ms: one slow request either side moves it)  (target: <= {target:g}x)")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
