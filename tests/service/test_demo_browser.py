"""The demo page end to end in headless Chromium (playwright driving the system's chromium, WebGL
through SwiftShader, offline): with an API key set, the page asks for it; a photo and a shape are
posted through the page; the three.js viewer fires its load event with a non-empty mesh whose
pixels are drawn; a download re-requests the mesh in another format; a screenshot is saved.

Skipped only when no Chromium executable is found (PLAYWRIGHT_CHROMIUM, /usr/bin/chromium,
chromium or chromium-browser on PATH): ``apt-get install chromium`` and ``pip install playwright``."""

from __future__ import annotations

from pathlib import Path

import trimesh

from .conftest import KEY


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

    # the photo is shown; where the mask is unsure (X-Mask-Confidence under 0.6) the page asks for a box
    assert page.is_visible("#photo")
    glb = trimesh.creation.box().export(file_type="glb")
    for sure, asks in (("0.42", True), ("0.91", False)):
        def answer(route, request, sure=sure):           # the shape request answered with this confidence
            if "debug=mask" in request.url:
                route.fulfill(status=422, content_type="application/json", body='{"error": {"code": "no_mask"}}')
            else:
                route.fulfill(status=200, body=glb, headers={"Content-Type": "model/gltf-binary", "X-Mask": "network",
                                                             "X-Mask-Confidence": sure})
        page.route("**/v1/image-to-shape*", answer)
        before = page.evaluate("() => window.aocnnDemo.loads + window.aocnnDemo.errors")
        page.click("#run")
        page.wait_for_function(f"() => window.aocnnDemo.loads + window.aocnnDemo.errors > {before}", timeout=60_000)
        page.unroute("**/v1/image-to-shape*")
        assert f"confidence {sure}" in page.inner_text("#s-mask")
        assert page.inner_text("#box-text").startswith("the mask is unsure") == asks, page.inner_text("#box-text")
    # a box dragged on it goes with the next request, whose mask is drawn first
    requests = []
    page.on("request", lambda r: requests.append(r.url))
    area = page.locator("#photo").bounding_box()
    page.mouse.move(area["x"] + 0.2 * area["width"], area["y"] + 0.2 * area["height"])
    page.mouse.down()
    page.mouse.move(area["x"] + 0.8 * area["width"], area["y"] + 0.9 * area["height"], steps=5)
    page.mouse.up()
    assert page.inner_text("#box-text").startswith("box ") and page.is_enabled("#clear-box")
    before = page.evaluate("() => window.aocnnDemo.loads + window.aocnnDemo.errors")
    page.click("#run")
    page.wait_for_function(f"() => window.aocnnDemo.loads + window.aocnnDemo.errors > {before}", timeout=120_000)
    posts = [u for u in requests if "/v1/image-to-shape" in u]
    assert "debug=mask" in posts[0] and all("box=" in u for u in posts), posts

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
    assert page.inner_text("#s-surface") == "watertight (closed)"           # the page shows the closed mesh first
    assert page.inner_text("#s-mesh") == f"{detail['triangles']} / {detail['vertices']}"
    page.wait_for_timeout(300)
    assert drawn_fraction(page) > 0.01, "the mesh covers almost no pixel of the viewer"
    page.select_option("#surface", "patches")                             # the paper's patches on request
    patches = run_example(page, "airplane.obj")
    assert patches["loaded"] and page.inner_text("#s-surface") == "patches (open)"
    assert patches["detail"]["triangles"] != detail["triangles"]
    page.select_option("#surface", "watertight")

    # downloads re-request the mesh in the chosen format
    for fmt, magic in (("glb", b"glTF"), ("obj", b"# adaptive-ocnn"), ("ply", b"ply\n")):
        with page.expect_download() as info:
            page.click(f'#downloads button[data-format="{fmt}"]')
        path = Path(info.value.path())
        assert info.value.suggested_filename == f"octree.{fmt}"
        assert path.read_bytes().startswith(magic)

    # a z-up scan: the page sends the up axis chosen to the completion endpoint
    page.select_option("#up", "z")
    with page.expect_request(lambda r: "/v1/complete" in r.url) as sent:
        scan = run_example(page, "car_partial_scan.ply")
    assert "up=z" in sent.value.url, sent.value.url
    assert scan["loaded"] or "empty_output" in scan["status"], scan["status"]
    if scan["loaded"]:
        assert page.inner_text("#s-dropped") == "0"                      # the example scan has no strays
    page.select_option("#up", "y")

    shot = tmp_path / "demo.png"
    page.screenshot(path=str(shot), full_page=True)
    assert shot.stat().st_size > 10_000
    print(f"screenshot: {shot}")
    context.close()
    assert not problems, problems
