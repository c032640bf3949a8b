"""The request body limit at the ASGI level, as a streaming client sends it: chunks without a
Content-Length are added up (413 once their sum passes the limit, whatever each chunk's size),
and a body of exactly the limit is accepted, with or without a Content-Length."""

from __future__ import annotations

import asyncio
import json

import pytest

from service.app import create_app
from service.engine import Engine
from service.settings import Settings

LIMIT = 64 * 1024


@pytest.fixture(scope="module")
def app(models_dir):
    engine = Engine(Settings(models_dir=models_dir, max_body_bytes=LIMIT))
    engine.load()
    return create_app(engine.settings, engine)


def multipart(size: int) -> tuple[bytes, bytes]:
    """A multipart body of exactly ``size`` bytes: a small point cloud in the ``shape`` field and a
    filler field that pads it; and its content type."""
    boundary = b"limit-test-boundary"
    cloud = "".join(f"{x} {y} {(x * x + y * y) ** 0.5:.4f}\n" for x in range(-8, 9) for y in range(-8, 9)).encode()
    head = (b"--" + boundary + b'\r\nContent-Disposition: form-data; name="shape"; filename="c.xyz"\r\n'
            b"Content-Type: text/plain\r\n\r\n" + cloud + b"\r\n--" + boundary
            + b'\r\nContent-Disposition: form-data; name="filler"\r\n\r\n')
    tail = b"\r\n--" + boundary + b"--\r\n"
    pad = size - len(head) - len(tail)
    assert pad >= 0
    return head + b"x" * pad + tail, b"multipart/form-data; boundary=" + boundary


def post(app, body: bytes, content_type: bytes, chunk: int, content_length: bool) -> tuple[int, dict]:
    """POST /v1/octree?depth=4 through the ASGI interface, the body in ``chunk``-byte messages."""
    headers = [(b"content-type", content_type)]
    if content_length:
        headers.append((b"content-length", str(len(body)).encode()))
    scope = {"type": "http", "asgi": {"version": "3.0"}, "http_version": "1.1", "method": "POST",
             "scheme": "http", "path": "/v1/octree", "raw_path": b"/v1/octree", "query_string": b"depth=4",
             "root_path": "", "headers": headers, "client": ("127.0.0.1", 1), "server": ("127.0.0.1", 80)}
    parts = [body[i:i + chunk] for i in range(0, len(body), chunk)] or [b""]
    messages = [{"type": "http.request", "body": p, "more_body": i < len(parts) - 1} for i, p in enumerate(parts)]
    sent = []

    async def receive():
        if messages:
            return messages.pop(0)
        await asyncio.sleep(3600)                         # the client keeps the connection open
        return {"type": "http.disconnect"}

    async def send(message):
        sent.append(message)

    asyncio.run(app(scope, receive, send))
    start = next(m for m in sent if m["type"] == "http.response.start")
    body_out = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    return start["status"], (json.loads(body_out) if body_out.startswith(b"{") else {})


@pytest.mark.parametrize("chunk", [1024, 16 * 1024, LIMIT])
def test_chunks_without_a_length_are_added_up(app, chunk):
    body, kind = multipart(LIMIT + 1)
    status, answer = post(app, body, kind, chunk, content_length=False)
    assert status == 413 and answer["error"]["code"] == "body_too_large"


@pytest.mark.parametrize("content_length", [False, True])
def test_a_body_of_exactly_the_limit_is_accepted(app, content_length):
    body, kind = multipart(LIMIT)
    assert len(body) == LIMIT
    status, _ = post(app, body, kind, 8 * 1024, content_length)
    assert status == 200


def test_a_declared_length_over_the_limit_is_refused_before_reading(app):
    body, kind = multipart(LIMIT + 1)
    status, answer = post(app, body, kind, LIMIT + 1, content_length=True)
    assert status == 413 and str(LIMIT) in answer["error"]["message"].replace(",", "")
