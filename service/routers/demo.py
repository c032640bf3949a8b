"""The demo page: ``GET /`` (upload a photo, a scan or a shape, or pick a bundled example, and see
the returned patch mesh in a three.js viewer), its static files under ``/demo/`` (three.js is
vendored next to them with its licence: no CDN) and the bundled examples under ``/demo/examples/``.

The page calls the public API (``/v1/...``) like any client, with the user's API key if one is set."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from ..errors import APIError

DEMO_DIR = Path(__file__).resolve().parents[1] / "demo"
EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"
"""The repository's ``examples/`` folder beside the ``service`` package (the Docker image copies it
there too); the demo offers whichever of its files exist."""

MEDIA_TYPES = {                     # explicit: slim images have no /etc/mime.types to guess from
    ".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
    ".md": "text/markdown; charset=utf-8", ".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg",
    ".svg": "image/svg+xml", ".ico": "image/x-icon", ".ply": "application/x-ply", ".obj": "model/obj",
    ".glb": "model/gltf-binary",
}
LICENCE_NAMES = {"LICENSE", "LICENCE", "LICENSE.txt", "LICENSE.md"}
EXAMPLE_ENDPOINTS = {               # file suffix -> (endpoint, multipart field) the page posts it to
    ".png": ("image-to-shape", "image"), ".jpg": ("image-to-shape", "image"), ".jpeg": ("image-to-shape", "image"),
    ".ply": ("complete", "points"), ".xyz": ("complete", "points"), ".npy": ("complete", "points"),
    ".obj": ("octree", "shape"), ".off": ("octree", "shape"), ".stl": ("octree", "shape"),
}

router = APIRouter(include_in_schema=False)


def _media_type(path: Path) -> str | None:
    if path.name in LICENCE_NAMES:
        return "text/plain; charset=utf-8"
    return MEDIA_TYPES.get(path.suffix.lower())


def _file(root: Path, relative: str) -> FileResponse:
    """``root/relative`` if it is a file of a served type inside ``root``, else a JSON 404."""
    path = (root / relative).resolve()
    media = _media_type(path)
    if media is None or not path.is_file() or not path.is_relative_to(root.resolve()):
        raise APIError(404, "not_found", f"no such file: {relative}", "see GET / for the demo page")
    cache = "no-cache" if root == DEMO_DIR and "vendor" not in path.parts else "public, max-age=86400"
    return FileResponse(path, media_type=media, headers={"Cache-Control": cache})


def examples() -> list[dict]:
    """The bundled examples the page offers, with the endpoint and field each is posted to."""
    out = []
    for path in sorted(EXAMPLES_DIR.glob("*")) if EXAMPLES_DIR.is_dir() else []:
        target = EXAMPLE_ENDPOINTS.get(path.suffix.lower())
        if path.is_file() and target and _media_type(path):
            out.append({"name": path.name, "url": f"demo/examples/{path.name}", "endpoint": target[0],
                        "field": target[1], "bytes": path.stat().st_size})
    return out


@router.get("/")
async def page() -> FileResponse:
    return _file(DEMO_DIR, "index.html")


@router.get("/demo/examples")
async def example_list() -> dict:
    return {"examples": examples()}


@router.get("/demo/examples/{name}")
async def example(name: str) -> FileResponse:
    if not any(e["name"] == name for e in examples()):
        raise APIError(404, "not_found", f"no such example: {name}", "GET /demo/examples lists them")
    return _file(EXAMPLES_DIR, name)


@router.get("/demo/{path:path}")
async def static(path: str) -> FileResponse:
    return _file(DEMO_DIR, path)
