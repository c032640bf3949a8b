"""The demo page end to end in headless Chromium (playwright driving the system's chromium, WebGL
through SwiftShader, offline): with an API key set, the page asks for it; a photo and a shape are
posted through the page; the three.js viewer fires its load event with a non-empty mesh whose
pixels are drawn; a download re-requests the mesh in another format; a screenshot is saved.

Skipped only when no Chromium executable is found (PLAYWRIGHT_CHROMIUM, /usr/bin/chromium,
chromium or chromium-browser on PATH): ``apt-get install chromium`` and ``pip install playwright``."""

from __future__ import annotations

import os
import shutil
import socket
import threading
import time
from pathlib import Path

import pytest

from service.app import create_app
from service.settings import Settings

KEY = "browser-test-key"
LAUNCH_ARGS = ["--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"]


def chromium_executable() -> str | None:
    candidates = [os.environ.get("PLAYWRIGHT_CHROMIUM"), "/usr/bin/chromium", shutil.which("chromium"),
                  shutil.which("chromium-browser")]
    return next((c for c in candidates if c and os.access(c, os.X_OK)), None)


@pytest.fixture(scope="module")
def browser():
    exe = chromium_executable()
    if exe is None:
        pytest.skip("no Chromium executable (set PLAYWRIGHT_CHROMIUM, or apt-get install chromium)")
    from playwright.sync_api import sync_playwright     # the dev extra; not a reason to skip

    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=exe, args=LAUNCH_ARGS)
        yield b
        b.close()


@pytest.fixture(scope="module")
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


def run_example(page, name: str, timeout_ms: int = 120_000) -> dict:
    """Choose a bundled example, press Run and wait for the viewer (or an error)."""
    before = page.evaluate("() => [window.aocnnDemo.loads, window.aocnnDemo.errors]")
    page.click(f'#examples button[data-example="{name}"]')
    page.wait_for_function(f"() => document.getElementById('chosen').textContent.includes({name!r})")
    page.click("#run")
    page.wait_for_function(f"() => window.aocnnDemo.loads > {before[0]} || window.aocnnDemo.errors > {before[1]}",
                           timeout=timeout_ms)
    loaded = page.evaluate(f"() => window.aocnnDemo.loads > {before[0]}")
    return {"loaded": loaded, "status": page.inner_text("#status"),
            "detail": page.evaluate("() => window.aocnnDemo.last")}


def drawn_fraction(page) -> float:
    """The fraction of the viewer canvas's pixels the mesh covers (the clear colour is transparent)."""
    return page.evaluate("""() => {
        const gl = document.querySelector('#viewer canvas');
        const c = document.createElement('canvas');
        c.width = gl.width; c.height = gl.height;
        const ctx = c.getContext('2d');
        ctx.drawImage(gl, 0, 0);
        const px = ctx.getImageData(0, 0, c.width, c.height).data;
        let n = 0;
        for (let i = 3; i < px.length; i += 4) if (px[i] > 0) n++;
        return n / (c.width * c.height);
    }""")


def test_demo_page_in_chromium(browser, server, tmp_path):
    context = browser.new_context(viewport={"width": 1280, "height": 900}, accept_downloads=True)
    page = context.new_page()
    problems = []
    page.on("pageerror", lambda e: problems.append(f"page error: {e}"))
    page.on("requestfailed", lambda r: problems.append(f"request failed: {r.url}"))
    page.on("request", lambda r: r.url.startswith(server) or r.url.startswith(("blob:", "data:"))
            or problems.append(f"request to another origin: {r.url}"))
    page.goto(server)

    # the API needs a key: the page says so, then lists the models once it is given
    page.wait_for_function("() => document.getElementById('models').textContent.includes('API key')")
    page.fill("#key", KEY)
    page.dispatch_event("#key", "change")
    page.wait_for_function("() => document.getElementById('models').textContent.startsWith('serving')")
    assert "image-to-shape" in page.inner_text("#models")

    # a photo through the page; a random-weight image model may decode nothing (422 empty_output)
    photo = run_example(page, "chair_photo.jpg")
    if photo["loaded"]:
        assert photo["detail"]["vertices"] > 0 and photo["detail"]["triangles"] > 0
    else:
        assert "empty_output" in photo["status"], photo["status"]

    # a shape's adaptive octree: always a real mesh
    shape = run_example(page, "airplane.obj")
    assert shape["loaded"], shape["status"]
    detail = shape["detail"]
    assert detail["vertices"] > 0 and detail["triangles"] > 0 and detail["meshes"] >= 1
    viewer = page.locator("#viewer")
    assert viewer.get_attribute("data-state") == "loaded"
    assert int(viewer.get_attribute("data-triangles")) == detail["triangles"]
    assert int(page.inner_text("#s-nodes")) > 0
    assert ":" in page.inner_text("#s-leaves")
    assert page.inner_text("#s-mesh") == f"{detail['triangles']} / {detail['vertices']}"
    page.wait_for_timeout(300)
    assert drawn_fraction(page) > 0.01, "the mesh covers almost no pixel of the viewer"

    # downloads re-request the mesh in the chosen format
    for fmt, magic in (("glb", b"glTF"), ("obj", b"# adaptive-ocnn"), ("ply", b"ply\n")):
        with page.expect_download() as info:
            page.click(f'#downloads button[data-format="{fmt}"]')
        path = Path(info.value.path())
        assert info.value.suggested_filename == f"octree.{fmt}"
        assert path.read_bytes().startswith(magic)

    shot = tmp_path / "demo.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 10_000
    print(f"screenshot: {shot}")
    context.close()
    assert not problems, problems
