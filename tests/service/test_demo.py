"""The demo page (GET /): its static files, the vendored three.js and its licence, the bundled
examples, and no request to any other origin (no CDN).  The browser test is test_demo_browser.py."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from service.routers.demo import DEMO_DIR, EXAMPLES_DIR

from .conftest import make_client

OWN_FILES = ["index.html", "app.js", "style.css"]
VENDORED = ["three.module.js", "three.core.js", "addons/loaders/GLTFLoader.js", "addons/controls/OrbitControls.js",
            "addons/utils/BufferGeometryUtils.js", "addons/utils/SkeletonUtils.js"]
EXAMPLES = {"chair.png": ("image-to-shape", "image/png"), "chair_photo.jpg": ("image-to-shape", "image/jpeg"),
            "car_partial_scan.ply": ("complete", "application/x-ply"), "airplane.obj": ("octree", "model/obj")}


def test_page(client):
    r = client.get("/")
    assert r.status_code == 200
    assert r.headers["content-type"] == "text/html; charset=utf-8"
    html = r.text
    assert "<title>Adaptive O-CNN" in html
    for needed in ('src="demo/app.js"', 'href="demo/style.css"', '"three": "./demo/vendor/three/three.module.js"',
                   'id="viewer"', 'id="key"', 'type="file"'):
        assert needed in html
    for fmt in ("glb", "gltf", "ply", "obj"):
        assert f'data-format="{fmt}"' in html


@pytest.mark.parametrize("name, media", [("app.js", "text/javascript"), ("style.css", "text/css"),
                                         ("index.html", "text/html")])
def test_static_files(client, name, media):
    r = client.get(f"/demo/{name}")
    assert r.status_code == 200
    assert r.headers["content-type"].split(";")[0] == media
    assert r.content == (DEMO_DIR / name).read_bytes()


@pytest.mark.parametrize("name", VENDORED)
def test_vendored_three(client, name):
    r = client.get(f"/demo/vendor/three/{name}")
    assert r.status_code == 200
    assert r.headers["content-type"].split(";")[0] == "text/javascript"
    assert r.content == (DEMO_DIR / "vendor" / "three" / name).read_bytes()
    assert len(r.content) > 1000


def test_vendored_licence(client):
    r = client.get("/demo/vendor/three/LICENSE")
    assert r.status_code == 200
    assert r.headers["content-type"].startswith("text/plain")
    assert "The MIT License" in r.text and "three.js authors" in r.text
    assert "LICENSE" in client.get("/").text                   # the page links to it


def test_every_module_import_resolves():
    """Each relative or mapped import of the page's modules names a vendored file (no CDN)."""
    imports = {"three": DEMO_DIR / "vendor/three/three.module.js"}
    todo = [DEMO_DIR / "app.js", *(DEMO_DIR / "vendor/three" / v for v in VENDORED)]
    for path in todo:
        for spec in re.findall(r"""^\s*(?:import|export)\b[^'"]*?from\s*['"]([^'"]+)['"]""", path.read_text(), re.M):
            if spec in imports:
                target = imports[spec]
            elif spec.startswith("three/addons/"):
                target = DEMO_DIR / "vendor/three/addons" / spec.removeprefix("three/addons/")
            else:
                assert spec.startswith("."), f"{path.name} imports {spec}"
                target = (path.parent / spec).resolve()
            assert target.is_file(), f"{path.name}: {spec} -> {target}"


def test_no_external_urls():
    """The page, its script and its style load nothing from another origin; the vendored modules
    import nothing from one (their comments do mention web addresses)."""
    for name in OWN_FILES:
        text = (DEMO_DIR / name).read_text()
        assert not re.search(r"https?://|//[a-z0-9.-]+\.[a-z]{2,}/", text, re.I), name
    for path in (DEMO_DIR / "vendor").rglob("*.js"):
        text = path.read_text()
        assert not re.search(r"""^\s*(?:import|export)\b[^;]*?\bfrom\s*['"](?:https?:)?//""", text, re.M), path
        assert not re.search(r"""\bimport\s*\(\s*['"](?:https?:)?//""", text), path
        assert not re.search(r"""importScripts\s*\(\s*['"]https?:""", text), path


def test_examples_listed_and_served(client):
    listed = {e["name"]: e for e in client.get("/demo/examples").json()["examples"]}
    for name, (endpoint, media) in EXAMPLES.items():
        assert (EXAMPLES_DIR / name).is_file(), name
        assert listed[name]["endpoint"] == endpoint
        r = client.get("/" + listed[name]["url"])
        assert r.status_code == 200
        assert r.headers["content-type"].split(";")[0] == media
        assert r.content == (EXAMPLES_DIR / name).read_bytes()


@pytest.mark.parametrize("path", ["/demo/../settings.py", "/demo/%2e%2e/settings.py", "/demo/vendor/../../app.py",
                                  "/demo/examples/../README.md", "/demo/nothing.js", "/demo/examples/missing.png",
                                  "/demo/vendor/three/VENDORED.txt"])
def test_no_file_outside_the_demo(client, path):
    r = client.get(path)
    assert r.status_code == 404
    assert r.json()["error"]["code"] == "not_found"


def test_page_needs_no_key_but_the_api_does(models_dir):
    with make_client(models_dir, api_keys="s3cret") as c:
        assert c.get("/").status_code == 200
        assert c.get("/demo/app.js").status_code == 200
        assert c.get("/demo/examples").status_code == 200
        assert c.get("/v1/models").status_code == 401
        assert c.get("/v1/models", headers={"Authorization": "Bearer s3cret"}).status_code == 200
    assert "Authorization" in (DEMO_DIR / "app.js").read_text()       # the page sends the pasted key


def test_page_calls_the_existing_endpoints():
    js = (DEMO_DIR / "app.js").read_text()
    for endpoint, field in (("image-to-shape", "image"), ("complete", "points"), ("octree", "shape"),
                            ("classify", "shape")):
        assert re.search(rf"'{endpoint}': {{ field: '{field}'", js), endpoint
    assert "v1/models" in js and "format" in js


def test_demo_files_are_package_data():
    """pyproject.toml ships service/demo/** in the wheel (the page works from an installed package)."""
    import tomllib
    pyproject = tomllib.loads((Path(__file__).parents[2] / "pyproject.toml").read_text())
    globs = pyproject["tool"]["setuptools"]["package-data"]["service"]
    shipped = {p for g in globs for p in (DEMO_DIR.parent).glob(g) if p.is_file()}
    assert {p for p in DEMO_DIR.rglob("*") if p.is_file()} <= shipped
