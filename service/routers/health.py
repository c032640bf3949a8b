"""Liveness and readiness (also at the Open Inference Protocol's /v2 paths) and /metrics."""

from __future__ import annotations

from fastapi import APIRouter, Depends, Response
from fastapi.responses import JSONResponse
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from ..deps import engine
from ..engine import Engine
from ..schemas import Health, Readiness

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health, summary="Live: the process answers")
@router.get("/v2/health/live", response_model=Health, summary="Live (Open Inference Protocol path)")
async def live() -> Health:
    return Health()


@router.get("/readyz", response_model=Readiness, responses={503: {"model": Readiness}},
            summary="Ready: every bundle loaded, verified and warmed up")
@router.get("/v2/health/ready", response_model=Readiness, responses={503: {"model": Readiness}},
            summary="Ready (Open Inference Protocol path)")
async def ready(eng: Engine = Depends(engine)):
    body = Readiness(ready=eng.ready, models=sorted(eng.models))
    return body if eng.ready else JSONResponse(body.model_dump(), status_code=503)


@router.get("/metrics", summary="Prometheus metrics", response_class=Response)
async def metrics(eng: Engine = Depends(engine)) -> Response:
    return Response(generate_latest(eng.metrics.registry), media_type=CONTENT_TYPE_LATEST)
