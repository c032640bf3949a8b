"""The API pages work offline and the schema lists every route: /docs and /redoc load their
scripts from the service (never a CDN) under a policy that lets the browser load nothing from
another host, and in headless Chromium with every request to another host blocked (none is even
attempted), Swagger UI shows every operation of the schema and ReDoc renders them too."""

from __future__ import annotations

import re
from urllib.parse import urlparse

import pytest

from service.app import ROUTERS


def schema_operations(spec: dict) -> set[tuple[str, str]]:
    return {(method.upper(), path) for path, item in spec["paths"].items() for method in item}


def test_every_route_is_in_the_schema(client):
    spec = client.get("/openapi.json").json()
    routes = {(method, re.sub(r":\w+}", "}", route.path))
              for router in ROUTERS for route in router.routes for method in route.methods - {"HEAD"}}
    assert len(routes) >= 18
    assert routes == schema_operations(spec)
    assert {"/v2/health/live", "/v2/health/ready", "/docs", "/redoc"} <= set(spec["paths"])


@pytest.mark.parametrize("page", ["/docs", "/redoc"])
def test_the_api_pages_name_no_other_host(client, page):
    html = client.get(page)
    assert html.status_code == 200 and html.headers["content-type"].startswith("text/html")
    policy = dict(p.strip().split(" ", 1) for p in html.headers["content-security-policy"].split(";"))
    assert policy["default-src"] == "'self'" and policy["img-src"] == "'self' data:"
    assert not re.findall(r"(?:src|href)=[\"']?(?:https?:)?//", html.text), html.text
    for ref in re.findall(r"/apidocs/[\w./-]+", html.text):
        asset = client.get(ref)
        assert asset.status_code == 200 and len(asset.content) > 500, ref


def test_assets_outside_their_folder_or_of_unknown_types_are_404(client):
    for path in ("/apidocs/../app.py", "/apidocs/%2e%2e/app.py", "/apidocs/VENDORED.txt", "/apidocs/nothing.js"):
        r = client.get(path)
        assert r.status_code == 404 and r.json()["error"]["code"] == "not_found", path
    assert client.get("/apidocs/swagger-ui/LICENSE").headers["content-type"].startswith("text/plain")


def offline_page(browser, server):
    """A page whose requests to any host but the service are aborted and recorded."""
    context = browser.new_context(viewport={"width": 1280, "height": 900})
    blocked, errors = [], []
    host = urlparse(server).netloc

    def only_the_service(route):
        url = urlparse(route.request.url)
        if url.scheme in ("http", "https", "ws", "wss") and url.netloc != host:
            blocked.append(route.request.url)
            return route.abort()
        return route.continue_()

    context.route("**/*", only_the_service)
    page = context.new_page()
    page.on("pageerror", lambda e: errors.append(str(e)))
    return context, page, blocked, errors


def test_swagger_ui_shows_every_operation_offline(browser, server, client):
    operations = schema_operations(client.get("/openapi.json").json())
    context, page, blocked, errors = offline_page(browser, server)
    page.goto(server + "docs")
    page.wait_for_selector(".opblock", timeout=60_000)
    shown = page.eval_on_selector_all(
        ".opblock", "els => els.map(e => [e.querySelector('.opblock-summary-method').textContent.trim(),"
                    " e.querySelector('.opblock-summary-path').getAttribute('data-path')])")
    context.close()
    assert {(m, p) for m, p in shown} == operations
    assert not blocked and not errors, (blocked, errors)


def test_redoc_renders_every_operation_offline(browser, server, client):
    operations = schema_operations(client.get("/openapi.json").json())
    context, page, blocked, errors = offline_page(browser, server)
    page.goto(server + "redoc")
    page.wait_for_selector("[data-section-id^='operation/']", timeout=60_000)
    count = page.eval_on_selector_all("[data-section-id^='operation/']", "els => els.length")
    context.close()
    assert count == len(operations)
    assert not blocked and not errors, (blocked, errors)
