"""Run the Adaptive O-CNN inference service (FastAPI + onnxruntime, no torch) with the bundles of
a models folder; every setting is an AOCNN_* environment variable (--settings lists them), and
the options override three of them.  Also installed as ``aocnn-serve``."""

from __future__ import annotations

import sys
import time

import uvicorn
from pydantic import ValidationError

from model.cli import command_parser

from .app import create_app
from .engine import Engine, StartupError
from .settings import Settings, describe_error, settings_table


def main(argv: list[str] | None = None) -> int:
    ap = command_parser("python -m service", __doc__, [
        "python -m service                      # http://127.0.0.1:8000/ (demo page), /docs (the API)",
        "AOCNN_CONCURRENCY=1 AOCNN_THREADS=2 python -m service --port 9000", "python -m service --settings"])
    ap.add_argument("--host", default=None, help="bind address (default AOCNN_HOST or 127.0.0.1)")
    ap.add_argument("--port", type=int, default=None, help="port (default AOCNN_PORT or 8000)")
    ap.add_argument("--models-dir", default=None, help="bundles folder (default AOCNN_MODELS_DIR or models/bundles)")
    ap.add_argument("--settings", action="store_true", help="print the table of AOCNN_* settings and exit")
    ap.add_argument("--warm-up", action="store_true", help="load, verify and warm up every bundle (compiling the "
                    "kernels into their cache), then exit without serving: what an image build runs once")
    args = ap.parse_args(argv)
    if args.settings:
        print(settings_table(), end="")
        return 0
    given = {"host": args.host, "port": args.port, "models_dir": args.models_dir}
    overrides = {k: v for k, v in given.items() if v is not None}
    try:
        settings = Settings(**overrides)
    except ValidationError as exc:                  # a bad AOCNN_* value or option
        print(f"error: {describe_error(exc, {k: '--' + k.replace('_', '-') for k in overrides})}", file=sys.stderr)
        return 2
    engine = Engine(settings)
    try:
        engine.load()                               # verify every bundle before binding the port
    except StartupError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    if args.warm_up:
        started = time.perf_counter()
        engine.warm_up()
        print(f"warmed up {', '.join(sorted(engine.models))} in {time.perf_counter() - started:.1f} s")
        return 0
    uvicorn.run(create_app(settings, engine), host=settings.host, port=settings.port, log_level="info")
    return 0


if __name__ == "__main__":
    sys.exit(main())
