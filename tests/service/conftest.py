"""A service over small random-weight bundles of every served task: image-to-shape, completion
and classification."""

from __future__ import annotations

import json
import shutil

import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.settings import Settings

from ..export.conftest import clouds, exported  # noqa: F401  (fixtures)


@pytest.fixture(scope="session")
def models_dir(exported, tmp_path_factory):
    root = tmp_path_factory.mktemp("models")
    shutil.copytree(exported("image-resnet18")[2], root / "image-to-shape")
    shutil.copytree(exported("completion-aocnn")[2], root / "completion")
    shutil.copytree(exported("classify-aocnn")[2], root / "classify")
    for task in ("completion", "classify"):
        meta = json.loads((root / task / "model.json").read_text())
        meta.update(name=f"{task}-test")
        (root / task / "model.json").write_text(json.dumps(meta))
    return root


def make_client(models_dir, **settings) -> TestClient:
    return TestClient(create_app(Settings(models_dir=models_dir, **settings)))


@pytest.fixture(scope="session")
def client(models_dir):
    with make_client(models_dir) as c:
        yield c
