"""ASGI middleware that refuses request bodies above the size limit (413) before they are read."""

from __future__ import annotations

import json


class BodyLimit:
    """Checks Content-Length up front and adds up the streamed (chunked) bytes; answers 413 as JSON.

    Once the streamed bytes pass the limit, the app's next read sees the client gone and whatever
    the app then answers (a form parser's 400, say) is dropped for the 413: the body limit does
    not depend on how the endpoint reads its body.
    """

    def __init__(self, app, max_bytes: int):
        self.app, self.max_bytes = app, max_bytes

    async def __call__(self, scope, receive, send):
        if scope["type"] != "http":
            return await self.app(scope, receive, send)
        length = dict(scope.get("headers") or []).get(b"content-length")
        if length is not None and (not length.isdigit() or int(length) > self.max_bytes):
            return await self._refuse(send)
        seen, over, started = 0, False, False

        async def limited():
            nonlocal seen, over
            if over:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                seen += len(message.get("body", b""))
                if seen > self.max_bytes:
                    over = True
                    return {"type": "http.disconnect"}
            return message

        async def guarded(message):
            nonlocal started
            if over:
                return
            started = started or message["type"] == "http.response.start"
            await send(message)

        try:
            await self.app(scope, limited, guarded)
        except Exception:
            if not over:
                raise
        if over and not started:
            await self._refuse(send)

    async def _refuse(self, send):
        body = json.dumps({"error": {
            "code": "body_too_large", "message": f"the request body is larger than the limit of {self.max_bytes:,} bytes",
            "hint": "send a smaller file (or raise AOCNN_MAX_BODY_BYTES)"}}).encode()
        await send({"type": "http.response.start", "status": 413,
                    "headers": [(b"content-type", b"application/json"), (b"content-length", str(len(body)).encode())]})
        await send({"type": "http.response.body", "body": body})
