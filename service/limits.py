"""ASGI middleware that refuses request bodies above the size limit (413) before they are read."""

from __future__ import annotations

import json

from .errors import APIError


class BodyLimit:
    """Checks Content-Length up front and counts streamed (chunked) bytes; answers 413 as JSON."""

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = dict(scope.get("headers") or []).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_bytes):
            return await self._refuse(send)
        seen = 0

        async def limited():
            nonlocal seen
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:      # raised inside the endpoint's body read: the app's handler answers
                    raise APIError(413, *self._error())
            return message

        await self.app(scope, limited, send)

    def _error(self) -> tuple[str, str, str]:
        return ("body_too_large", f"the request body is larger than the limit of {self.max_bytes:,} bytes",
                "send a smaller file (or raise AOCNN_MAX_BODY_BYTES)")

    async def _refuse(self, send):
        code, message, hint = self._error()
        body = json.dumps({"error": {"code": code, "message": message, "hint": hint}}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})
