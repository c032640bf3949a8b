"""Load test of the service: uvicorn on 127.0.0.1, an asyncio httpx2 client, fixed duration.

Starts ``python -m service`` on a free port (the bundled models unless ``--models-dir``), waits
for /readyz, then for each concurrency level keeps that many requests in flight for
``--seconds`` and reports p50/p95/p99 latency, throughput, errors (non-2xx), the server's RSS at
the start and end of the run (sampled every second from /proc), and the share of request time
spent outside the model (1 - (encoder + decoder) / latency, from the Server-Timing header).

    python -m bench.load [--endpoint image-to-shape] [--input examples/chair_photo.jpg]
                         [--concurrency 1 4] [--seconds 60] [--env AOCNN_CONCURRENCY=1 ...]
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import os
import socket
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx2 as httpx

from model.cli import command_parser

FIELDS = {"image-to-shape": "image", "complete": "points", "octree": "shape", "classify": "shape"}
TARGET_OUTSIDE = 0.15


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@contextlib.contextmanager
def serve(models_dir: str | None = None, env: dict[str, str] | None = None,
          cwd: str | None = None) -> Iterator[tuple[str, int]]:
    """``python -m service`` on a free port of 127.0.0.1 (the bundled models unless ``models_dir``;
    ``env``: AOCNN_* settings; ``cwd``: run from another checkout, its own code and models), ready
    (/readyz); yields its base URL and process id, and stops it."""
    port = _free_port()
    env = {**os.environ, **(env or {}), "AOCNN_PORT": str(port)}
    if models_dir:
        env["AOCNN_MODELS_DIR"] = models_dir
    server = subprocess.Popen([sys.executable, "-m", "service"], env=env, stdout=subprocess.DEVNULL,
                              stderr=subprocess.PIPE, cwd=cwd)
    base = f"http://127.0.0.1:{port}"
    try:
        for _ in range(240):
            try:
                if httpx.get(f"{base}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            if server.poll() is not None:
                raise RuntimeError(f"the service stopped: {server.stderr.read().decode()}")
            time.sleep(0.5)
        yield base, server.pid
    finally:
        server.terminate()
        server.wait(timeout=30)


def _rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def _stages(timing: str) -> dict[str, float]:
    """Seconds per stage of a Server-Timing header."""
    out = {}
    for part in timing.split(","):
        name, _, dur = part.strip().partition(";dur=")
        if dur:
            out[name] = float(dur) / 1e3
    return out


async def _run(url: str, field: str, data: bytes, name: str, concurrency: int, seconds: float, pid: int) -> dict:
    lat, outside, errors, codes, stages = [], [], 0, {}, {}
    rss = [_rss_mb(pid)]
    stop = time.perf_counter() + seconds

    async def worker(client: httpx.AsyncClient):
        nonlocal errors
        while time.perf_counter() < stop:
            t = time.perf_counter()
            r = await client.post(url, files={field: (name, data)})
            dt = time.perf_counter() - t
            codes[r.status_code] = codes.get(r.status_code, 0) + 1
            if r.status_code != 200:
                errors += 1
                continue
            lat.append(dt)
            spent = _stages(r.headers.get("server-timing", ""))
            outside.append(1 - (spent.get("encoder", 0) + spent.get("decoder", 0)) / dt)
            for stage, sec in spent.items():
                stages.setdefault(stage, []).append(sec)

    async def sample():
        while time.perf_counter() < stop:
            await asyncio.sleep(1)
            rss.append(_rss_mb(pid))

    async with httpx.AsyncClient(timeout=120, limits=httpx.Limits(max_connections=concurrency + 2)) as client:
        t0 = time.perf_counter()
        await asyncio.gather(sample(), *[worker(client) for _ in range(concurrency)])
        wall = time.perf_counter() - t0
    q = statistics.quantiles(lat, n=100) if len(lat) >= 2 else [float("nan")] * 99
    return {"concurrency": concurrency, "requests": len(lat) + errors, "errors": errors, "codes": codes,
            "throughput_rps": len(lat) / wall, "p50_ms": 1e3 * q[49], "p95_ms": 1e3 * q[94], "p99_ms": 1e3 * q[98],
            "outside_model_share": statistics.mean(outside) if outside else float("nan"),
            "rss_start_mb": rss[0], "rss_end_mb": rss[-1], "rss_max_mb": max(rss),
            "stage_ms": {k: 1e3 * statistics.mean(v) for k, v in stages.items()}}


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m bench.load", __doc__, ['python -m bench.load --seconds 20 --concurrency 1 4 16'])
    ap.add_argument("--endpoint", choices=sorted(FIELDS), default="image-to-shape", help="default image-to-shape")
    ap.add_argument("--input", default="examples/chair_photo.jpg", help="file to upload (default the example photo)")
    ap.add_argument("--query", default="", help="query parameters of every request, e.g. surface=patches (default: none)")
    ap.add_argument("--concurrency", type=int, nargs="+", default=[1, 4], help="requests in flight (default 1 4)")
    ap.add_argument("--seconds", type=float, default=60, help="duration per concurrency level (default 60)")
    ap.add_argument("--models-dir", default=None, help="bundles to serve (default the bundled ones)")
    ap.add_argument("--env", nargs="*", default=[], help="AOCNN_*=value settings for the server (default: none)")
    ap.add_argument("--json", default=None, help="also write the figures here (default: none)")
    args = ap.parse_args(argv)
    env = dict(e.split("=", 1) for e in args.env)
    with serve(args.models_dir, env) as (base, pid):
        data = Path(args.input).read_bytes()
        url = f"{base}/v1/{args.endpoint}" + (f"?{args.query}" if args.query else "")
        rows = [asyncio.run(_run(url, FIELDS[args.endpoint], data, Path(args.input).name,
                                 c, args.seconds, pid)) for c in args.concurrency]
    print(f"{args.endpoint}?{args.query}, {args.input}, {args.seconds:g} s per level, server env {args.env or 'defaults'}")
    print(f"{'conc':>4} {'req':>6} {'err':>4} {'rps':>7} {'p50 ms':>8} {'p95 ms':>8} {'p99 ms':>8} "
          f"{'outside model':>13} {'RSS start/end/max MB':>22}")
    for r in rows:
        print(f"{r['concurrency']:>4} {r['requests']:>6} {r['errors']:>4} {r['throughput_rps']:>7.2f} "
              f"{r['p50_ms']:>8.1f} {r['p95_ms']:>8.1f} {r['p99_ms']:>8.1f} {r['outside_model_share']:>13.0%} "
              f"{r['rss_start_mb']:>8.0f}/{r['rss_end_mb']:.0f}/{r['rss_max_mb']:.0f}")
        print("     mean ms per stage: " + ", ".join(f"{k} {v:.1f}" for k, v in r["stage_ms"].items()))
    print(f"targets: 0 errors and flat memory at concurrency 2x the CPUs; time outside the model <= "
          f"{TARGET_OUTSIDE:.0%} for image -> shape")
    if args.json:
        Path(args.json).write_text(json.dumps(rows, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
