"""Request dependencies: the engine of the app, and the optional API-key check."""

from __future__ import annotations

import hmac

from fastapi import Request

from .engine import Engine
from .errors import ServiceError


def engine(request: Request) -> Engine:
    return request.app.state.engine


def require_key(request: Request) -> None:
    """With AOCNN_API_KEYS set, every /v1 request needs ``Authorization: Bearer <key>``."""
    keys = request.app.state.engine.settings.keys()
    if not keys:
        return
    scheme, _, token = request.headers.get("authorization", "").partition(" ")
    if scheme.lower() != "bearer" or not any(hmac.compare_digest(token.strip(), k) for k in keys):
        raise ServiceError("unauthorized", "a valid API key is required",
                       "send the header 'Authorization: Bearer <key>'", {"WWW-Authenticate": "Bearer"})
