"""The FastAPI application: routers, error handlers, limits, CORS, metrics, and the lifespan that
loads, verifies and warms up every bundle before the service reports ready."""

from __future__ import annotations

import asyncio
import time
from contextlib import asynccontextmanager

from fastapi import FastAPI, Request
from fastapi.middleware.cors import CORSMiddleware

from . import errors
from .body_limit import BodyLimit
from .engine import Engine
from .routers import apidocs, demo, health, models, shapes
from .settings import Settings

ROUTERS = (shapes.router, models.router, health.router, demo.router, apidocs.router)
"""Every router of the app, in the order they match."""


API_DESCRIPTION = """A photo or a partial scan in, a 3D shape out (Adaptive O-CNN, onnxruntime).
Errors are JSON: `{"error": {"code", "message", "hint"}}`.

**Changelog**

- 2026-11-29: with `box=`, the foreground network sees the box with half its longest side of
  the photo about it, and the mask is then kept inside the box: a box drawn tightly around the
  object no longer loses it (validation photos: mask IoU 0.93 with a box, 0.87 before).
- 2026-11-28: `POST /v1/image-to-shape` takes `box=left,top,right,bottom` (x0,y0,x1,y1, the
  uploaded image's pixels): the object is looked for inside it. **`X-Crop-Box` is now
  left,top,right,bottom** (x0,y0,x1,y1), the order boxes come in; it was top,left,bottom,right.
  New header `X-Mask-Confidence`: how sure the foreground network's mask is at its edge (0 to 1).
"""


def create_app(settings: Settings | None = None, engine: Engine | None = None) -> FastAPI:
    """The app; bundles load when it starts (lifespan), so a bad bundle stops startup.
    ``engine``: one whose bundles are already loaded (``python -m service`` checks them first)."""
    settings = settings or (engine.settings if engine else Settings())

    @asynccontextmanager
    async def lifespan(app: FastAPI):
        eng = engine or Engine(settings)
        app.state.engine = eng
        if eng.limiter is None:
            eng.load()                                          # StartupError: fail fast
        await asyncio.get_running_loop().run_in_executor(None, eng.warm_up)
        yield
        eng.limiter.close()

    app = FastAPI(title="Adaptive O-CNN", version="1", lifespan=lifespan, docs_url=None, redoc_url=None,
                  description=API_DESCRIPTION)
    if engine is not None:
        app.state.engine = engine                               # usable without the lifespan (ASGI test tools)
    errors.install(app)
    for r in ROUTERS:
        app.include_router(r)
    if settings.origins():
        app.add_middleware(CORSMiddleware, allow_origins=settings.origins(), allow_methods=["GET", "POST"],
                           allow_headers=["Authorization", "Content-Type"],
                           expose_headers=["Content-Disposition", "X-Model-Name", "X-Model-Version",
                                           "X-Octree-Nodes", "X-Octree-Leaves", "X-Surface", "X-Mesh-Faces",
                                           "X-Mesh-Closed", "X-Mask", "X-Crop-Box", "X-Mask-Confidence",
                                           "X-Foreground-Ratio",
                                           "Server-Timing"])
    app.add_middleware(BodyLimit, max_bytes=settings.max_body_bytes)

    @app.middleware("http")
    async def count(request: Request, call_next):
        start = time.perf_counter()
        response = await call_next(request)
        route = request.scope.get("route")
        endpoint = getattr(route, "path", "unmatched")
        eng = getattr(request.app.state, "engine", None)
        if eng is not None:
            eng.metrics.requests.labels(endpoint, str(response.status_code)).inc()
            eng.metrics.latency.labels(endpoint).observe(time.perf_counter() - start)
        return response

    return app
