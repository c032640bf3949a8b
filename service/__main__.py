"""Run the service: ``python -m service`` (or ``aocnn-serve``); settings from AOCNN_* variables."""

from __future__ import annotations

import sys


def main(argv: list[str] | None = None) -> int:
    import argparse

    import uvicorn

    from .engine import StartupError
    from .settings import Settings

    ap = argparse.ArgumentParser(prog="python -m service", description=__doc__.splitlines()[0])
    ap.add_argument("--host", default=None, help="bind address (default AOCNN_HOST or 127.0.0.1)")
    ap.add_argument("--port", type=int, default=None, help="port (default AOCNN_PORT or 8000)")
    ap.add_argument("--models-dir", default=None, help="bundles folder (default AOCNN_MODELS_DIR or models/bundles)")
    args = ap.parse_args(argv)
    overrides = {k: v for k, v in {"host": args.host, "port": args.port, "models_dir": args.models_dir}.items()
                 if v is not None}
    try:
        settings = Settings(**overrides)
    except ValueError as exc:                       # pydantic's ValidationError: a bad AOCNN_* value
        print(f"error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
    from .app import create_app
    from .engine import Engine
    engine = Engine(settings)
    try:
        engine.load()                               # verify every bundle before binding the port
    except StartupError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    uvicorn.run(create_app(settings, engine), host=settings.host, port=settings.port, log_level="info")
    return 0


if __name__ == "__main__":
    sys.exit(main())
