"""The API pages, offline: ``GET /docs`` (Swagger UI) and ``GET /redoc`` (ReDoc) with their
scripts, styles and icon served from the package (``service/apidocs/``, vendored from npm with
their licences), so that they work where the service cannot reach the internet.  FastAPI's own
pages load them from a CDN; the app turns those off (``docs_url=None, redoc_url=None``)."""

from __future__ import annotations

from pathlib import Path

from fastapi import APIRouter, Request
from fastapi.openapi.docs import get_redoc_html, get_swagger_ui_html, get_swagger_ui_oauth2_redirect_html
from fastapi.responses import FileResponse, HTMLResponse

from ..errors import ErrorBody
from ..static import static_file

ASSETS_DIR = Path(__file__).resolve().parents[1] / "apidocs"
ASSETS = "/apidocs"
SWAGGER_PARAMETERS = {"validatorUrl": None}
"""Swagger UI would otherwise show a badge loaded from validator.swagger.io."""
CONTENT_SECURITY_POLICY = ("default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
                           "img-src 'self' data:; worker-src 'self' blob:; connect-src 'self'")
"""The pages may load only from the service: ReDoc's sidebar links an image on cdn.redoc.ly, which
the browser then never requests (the image is hidden when it fails to load).  Their inline
start-up scripts and the styles their libraries inject stay allowed."""


def _page(response: HTMLResponse) -> HTMLResponse:
    response.headers["Content-Security-Policy"] = CONTENT_SECURITY_POLICY
    return response

router = APIRouter(tags=["pages"])
HTML = {200: {"content": {"text/html": {}}}}


@router.get("/docs", response_class=HTMLResponse, responses=HTML, summary="This API in Swagger UI")
async def swagger_ui(request: Request) -> HTMLResponse:
    app = request.app
    return _page(get_swagger_ui_html(openapi_url=app.openapi_url, title=f"{app.title} - API",
                                     swagger_js_url=f"{ASSETS}/swagger-ui/swagger-ui-bundle.js",
                                     swagger_css_url=f"{ASSETS}/swagger-ui/swagger-ui.css",
                                     swagger_favicon_url=f"{ASSETS}/swagger-ui/favicon-32x32.png",
                                     oauth2_redirect_url="/docs/oauth2-redirect",
                                     swagger_ui_parameters=SWAGGER_PARAMETERS))


@router.get("/docs/oauth2-redirect", response_class=HTMLResponse, responses=HTML,
            summary="Swagger UI's OAuth2 redirect page")
async def swagger_ui_redirect() -> HTMLResponse:
    return _page(get_swagger_ui_oauth2_redirect_html())


@router.get("/redoc", response_class=HTMLResponse, responses=HTML, summary="This API in ReDoc")
async def redoc(request: Request) -> HTMLResponse:
    app = request.app
    return _page(get_redoc_html(openapi_url=app.openapi_url, title=f"{app.title} - API",
                                redoc_js_url=f"{ASSETS}/redoc/redoc.standalone.js",
                                redoc_favicon_url=f"{ASSETS}/swagger-ui/favicon-32x32.png", with_google_fonts=False))


@router.get(ASSETS + "/{path:path}", response_class=FileResponse,
            responses={200: {"description": "the file", "content": {"text/javascript": {}, "text/css": {},
                                                                   "image/png": {}, "text/plain": {}}},
                       404: {"model": ErrorBody, "description": "no such file"}},
            summary="The API pages' vendored scripts, styles and licences")
async def asset(path: str) -> FileResponse:
    return static_file(ASSETS_DIR, path, "public, max-age=86400", "the API pages are at /docs and /redoc")
