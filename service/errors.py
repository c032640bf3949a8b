"""Errors as JSON: every failure the client can fix is a 4xx saying what is wrong and what to do.

Body: ``{"error": {"code": "...", "message": "...", "hint": "..."}}``.  Unexpected exceptions become
a 500 with the same shape and no traceback (they are logged).
"""

from __future__ import annotations

import logging

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException as StarletteHTTPException

log = logging.getLogger("service")


class ErrorDetail(BaseModel):
    code: str
    message: str
    hint: str = ""


class ErrorBody(BaseModel):
    """The body of every error response."""

    error: ErrorDetail


STATUS = {
    "empty_input": 400, "invalid_image": 400, "invalid_points": 400, "too_few_points": 400,
    "unauthorized": 401, "not_found": 404,
    "image_too_large": 413, "input_too_large": 413, "too_many_points": 413,
    "unsupported_format": 415, "unsupported_image": 415,
    "empty_output": 422, "invalid_depth": 422, "invalid_request": 422, "no_foreground_network": 422,
    "no_mask": 422, "no_object": 422, "invalid_box": 422,
    "busy": 503, "no_model": 503, "timeout": 504}
"""Every error code the service answers with -> its HTTP status: the one place they are mapped."""


class ServiceError(Exception):
    """A request the service cannot serve, in its own terms: a stable ``code`` (a key of
    :data:`STATUS`, which gives the HTTP status), a message and what to do about it.  The engine,
    the input readers and the routers raise it; :func:`install`'s handler answers it."""

    def __init__(self, code: str, message: str, hint: str = "", headers: dict | None = None):
        if code not in STATUS:
            raise ValueError(f"unknown error code {code!r}: add it to service.errors.STATUS")
        super().__init__(message)
        self.code, self.message, self.hint, self.headers = code, message, hint, headers

    @property
    def status(self) -> int:
        return STATUS[self.code]


def error_response(status: int, code: str, message: str, hint: str = "", headers: dict | None = None) -> JSONResponse:
    body = ErrorBody(error=ErrorDetail(code=code, message=message, hint=hint))
    return JSONResponse(body.model_dump(), status_code=status, headers=headers)


ERROR_RESPONSES = {s: {"model": ErrorBody, "description": d} for s, d in {
    400: "the input cannot be used (the message says why)", 401: "missing or invalid API key",
    413: "the body or the input is too large", 415: "unsupported input format",
    422: "a missing or invalid field or parameter", 503: "busy or not ready (see Retry-After)",
    504: "the request took longer than the timeout"}.items()}


def install(app: FastAPI) -> None:
    """Register the handlers that turn every exception into an :class:`ErrorBody` response."""

    @app.exception_handler(ServiceError)
    async def _api(_: Request, exc: ServiceError):
        return error_response(exc.status, exc.code, exc.message, exc.hint, exc.headers)

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, exc: RequestValidationError):
        parts = []
        for e in exc.errors():
            where = ".".join(str(p) for p in e.get("loc", ()) if p != "body")
            parts.append(f"{where}: {e.get('msg', 'invalid')}")
        return error_response(422, "invalid_request", "; ".join(parts) or "invalid request",
                              "see /docs for the fields and parameters of this endpoint")

    @app.exception_handler(StarletteHTTPException)
    async def _http(_: Request, exc: StarletteHTTPException):
        code = {404: "not_found", 405: "method_not_allowed"}.get(exc.status_code, "http_error")
        return error_response(exc.status_code, code, str(exc.detail), "see /docs for the endpoints",
                              getattr(exc, "headers", None))

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception):
        log.exception("unexpected error on %s %s", request.method, request.url.path)
        return error_response(500, "internal_error", "the service failed on this request",
                              "this is a bug in the service; the request was not processed")
