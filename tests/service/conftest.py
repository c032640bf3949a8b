"""A service over small random-weight bundles of every served task: image-to-shape, completion
and classification; the same app on a real port, and headless Chromium for the browser tests."""

from __future__ import annotations

import json
import os
import shutil
import socket
import threading
import time

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings

from ..export.conftest import clouds, exported  # noqa: F401  (fixtures)


@pytest.fixture(scope="session")
def models_dir(exported, tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    shutil.copytree(exported("image-resnet18")[2], root / "image-to-shape")
    shutil.copytree(exported("completion-aocnn")[2], root / "completion")
    shutil.copytree(exported("classify-aocnn")[2], root / "classify")
    for task in ("completion", "classify"):
        meta = json.loads((root / task / "model.json").read_text())
        meta.update(name=f"{task}-test")
        (root / task / "model.json").write_text(json.dumps(meta))
    return root


@pytest.fixture(scope="session")
def foreground_models_dir(exported, tmp_path_factory):
    """The image bundle alone, with a foreground graph added: a random-weight ForegroundNet whose
    head says "object" everywhere (bias +4), so that the real graph's mask is known: the whole image."""
    import torch

    from export.bundle import GraphSpec
    from export.graphs import foreground_graph
    from model.files import sha256_file
    from model.image.mask import MaskSpec
    from model.networks.foreground import ForegroundNet

    root = tmp_path_factory.mktemp("foreground-models")
    folder = root / "image-to-shape"
    shutil.copytree(exported("image-resnet18")[2], folder)
    torch.manual_seed(0)
    net = ForegroundNet(width=4, levels=3)
    with torch.no_grad():
        net.head.bias.fill_(4.0)
    graph = foreground_graph(net.eval(), size=64)
    (folder / "foreground.onnx").write_bytes(graph.model)
    meta = json.loads((folder / "model.json").read_text())
    meta["graphs"]["foreground"] = GraphSpec("foreground", "foreground.onnx", sha256_file(folder / "foreground.onnx"),
                                             graph.inputs, graph.outputs).to_json()
    meta["input"]["foreground"] = MaskSpec(size=64).to_dict()
    (folder / "model.json").write_text(json.dumps(meta))
    return root


def make_client(models_dir, **settings) -> TestClient:
    return TestClient(create_app(Settings(models_dir=models_dir, **settings)))


@pytest.fixture(scope="session")
def client(models_dir):
    with make_client(models_dir) as c:
        yield c


KEY = "browser-test-key"
LAUNCH_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"]


def chromium_executable() -> str | None:
    candidates = [os.environ.get("PLAYWRIGHT_CHROMIUM"), "/usr/bin/chromium", shutil.which("chromium"),
                  shutil.which("chromium-browser")]
    return next((c for c in candidates if c and os.access(c, os.X_OK)), None)


@pytest.fixture(scope="module")
def browser():
    """Headless Chromium driven by playwright (the dev extra); skipped where no Chromium is installed.
    Module-scoped: playwright's synchronous API keeps an event loop running in this thread until it
    stops, and the tests after a browser module call asyncio.run."""
    exe = chromium_executable()
    if exe is None:
        pytest.skip("no Chromium browser: install it (apt-get install chromium) or set PLAYWRIGHT_CHROMIUM")
    from playwright.sync_api import sync_playwright

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=LAUNCH_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="session")
def server(models_dir):
    """The app on a free port (uvicorn in a thread), with an API key required on /v1."""
    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    app = create_app(Settings(models_dir=models_dir, api_keys=KEY))
    srv = uvicorn.Server(uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning"))
    thread = threading.Thread(target=srv.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 120
    while not srv.started:
        assert thread.is_alive() and time.monotonic() < deadline, "the server did not start"
        time.sleep(0.1)
    yield f"http://127.0.0.1:{port}/"
    srv.should_exit = True
    thread.join(30)
