"""Property-based requests generated from the app's own OpenAPI schema (schemathesis): no 5xx,
and every response matches the schema (status codes, content types, bodies)."""

from __future__ import annotations

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from service.app import create_app
from service.engine import Engine
from service.settings import Settings


@pytest.fixture(scope="module")
def app(models_dir):
    engine = Engine(Settings(models_dir=models_dir))
    engine.load()
    engine.warm_up()
    return create_app(engine.settings, engine)


schema = schemathesis.pytest.from_fixture("api_schema")


@pytest.fixture(scope="module")
def api_schema(app):
    return schemathesis.openapi.from_asgi("/openapi.json", app)


@schema.parametrize()
@settings(max_examples=15, deadline=None, suppress_health_check=list(HealthCheck))
def test_generated_requests_never_fail_the_server_and_match_the_schema(case):
    """Every check except positive-data acceptance: the schema says 'binary' for uploads, and random
    bytes that are not an image or a point cloud are rightly refused with a 4xx."""
    response = case.call()
    case.validate_response(response, excluded_checks=[schemathesis.checks.positive_data_acceptance])
