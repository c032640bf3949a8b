"""The demo page: ``GET /`` (upload a photo, a scan or a shape, or pick a bundled example, and see
the returned patch mesh in a three.js viewer), its static files under ``/demo/`` (three.js is
vendored next to them with its licence: no CDN) and the bundled examples under ``/demo/examples/``.

The page calls the public API (``/v1/...``) like any client, with the user's API key if one is set."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter
from fastapi.responses import FileResponse

from ..errors import ErrorBody, ServiceError
from ..static import media_type, static_file

DEMO_DIR = Path(__file__).resolve().parents[1] / "demo"
EXAMPLES_DIR = Path(__file__).resolve().parents[2] / "examples"
"""The repository's ``examples/`` folder beside the ``service`` package (the Docker image copies it
there too); the demo offers whichever of its files exist."""

EXAMPLE_ENDPOINTS = {               # file suffix -> (endpoint, multipart field) the page posts it to
    ".png": ("image-to-shape", "image"), ".jpg": ("image-to-shape", "image"), ".jpeg": ("image-to-shape", "image"),
    ".ply": ("complete", "points"), ".xyz": ("complete", "points"), ".npy": ("complete", "points"),
    ".obj": ("octree", "shape"), ".off": ("octree", "shape"), ".stl": ("octree", "shape"),
}

router = APIRouter(tags=["pages"])
NOT_FOUND = {404: {"model": ErrorBody, "description": "no such file"}}
FILE = {"description": "the file", "content": {"text/html": {}, "text/javascript": {}, "text/css": {}, "image/png": {},
                                              "text/plain": {}}}


def _file(root: Path, relative: str) -> FileResponse:
    cache = "no-cache" if root == DEMO_DIR and "vendor" not in Path(relative).parts else "public, max-age=86400"
    return static_file(root, relative, cache, "see GET / for the demo page")


def examples() -> list[dict]:
    """The bundled examples the page offers, with the endpoint and field each is posted to."""
    out = []
    for path in sorted(EXAMPLES_DIR.glob("*")) if EXAMPLES_DIR.is_dir() else []:
        target = EXAMPLE_ENDPOINTS.get(path.suffix.lower())
        if path.is_file() and target and media_type(path):
            out.append({"name": path.name, "url": f"demo/examples/{path.name}", "endpoint": target[0],
                        "field": target[1], "bytes": path.stat().st_size})
    return out


@router.get("/", response_class=FileResponse, responses={200: {"content": {"text/html": {}}}},
            summary="The demo page: upload a photo, a scan or a shape and see the returned mesh")
async def page() -> FileResponse:
    return _file(DEMO_DIR, "index.html")


@router.get("/demo/examples", summary="The bundled examples the demo page offers, with the endpoint each goes to")
async def example_list() -> dict:
    return {"examples": examples()}


@router.get("/demo/examples/{name}", response_class=FileResponse, responses={200: {"description": "the example file"},
                                                                          **NOT_FOUND},
            summary="One bundled example file")
async def example(name: str) -> FileResponse:
    if not any(e["name"] == name for e in examples()):
        raise ServiceError("not_found", f"no such example: {name}", "GET /demo/examples lists them")
    return _file(EXAMPLES_DIR, name)


@router.get("/demo/{path:path}", response_class=FileResponse, responses={200: FILE, **NOT_FOUND},
            summary="The demo page's scripts, styles and vendored three.js")
async def static(path: str) -> FileResponse:
    return _file(DEMO_DIR, path)
