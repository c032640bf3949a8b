"""Files the service serves as they are (the demo page, the API pages' vendored scripts, the
bundled examples): one guarded lookup with explicit media types and a JSON 404."""

from __future__ import annotations

from pathlib import Path

from fastapi.responses import FileResponse

from .errors import ServiceError

MEDIA_TYPES = {                     # explicit: slim images have no /etc/mime.types to guess from
    ".html": "text/html; charset=utf-8", ".js": "text/javascript; charset=utf-8", ".css": "text/css; charset=utf-8",
    ".md": "text/markdown; charset=utf-8", ".png": "image/png", ".jpg": "image/jpeg", ".jpeg": "image/jpeg",
    ".svg": "image/svg+xml", ".ico": "image/x-icon", ".ply": "application/x-ply", ".obj": "model/obj",
    ".glb": "model/gltf-binary",
}
LICENCE_NAMES = {"LICENSE", "LICENCE", "LICENSE.txt", "LICENSE.md", "NOTICE"}


def media_type(path: Path) -> str | None:
    """The media type a file is served with; None for a type the service does not serve."""
    if path.name in LICENCE_NAMES:
        return "text/plain; charset=utf-8"
    return MEDIA_TYPES.get(path.suffix.lower())


def static_file(root: Path, relative: str, cache: str, hint: str) -> FileResponse:
    """``root/relative`` if it is a file of a served type inside ``root``, else a JSON 404 with
    ``hint``; ``cache`` is its Cache-Control header."""
    path = (root / relative).resolve()
    media = media_type(path)
    if media is None or not path.is_file() or not path.is_relative_to(root.resolve()):
        raise ServiceError("not_found", f"no such file: {relative}", hint)
    return FileResponse(path, media_type=media, headers={"Cache-Control": cache})
