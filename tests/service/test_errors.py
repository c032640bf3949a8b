"""Errors have one owner: the engine, the input readers and the routers raise domain errors by
code, and one table maps every code to its HTTP status, each documented in the OpenAPI schema."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from service.errors import ERROR_RESPONSES, STATUS, ServiceError

SERVICE = Path(__file__).resolve().parents[2] / "service"


def test_every_code_raised_is_mapped_once_and_documented():
    raised = {m for f in SERVICE.rglob("*.py") for m in re.findall(r'ServiceError\(\s*"([a-z_]+)"', f.read_text())}
    assert raised and raised <= set(STATUS), raised - set(STATUS)
    assert {s for s in STATUS.values() if s != 404} <= set(ERROR_RESPONSES)
    assert ServiceError("no_model", "m").status == 503 and ServiceError("too_few_points", "m").status == 400


def test_an_unmapped_code_is_a_programming_error():
    with pytest.raises(ValueError, match="add it to service.errors.STATUS"):
        ServiceError("made_up", "message")
