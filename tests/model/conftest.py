"""A tiny procedural dataset shared by the network and training tests."""

import pytest

from model.data.dataset import BuildConfig, build_dataset, procedural_tasks

TINY = BuildConfig(depth=5, views=3, render_size=32, partial_scans=0, scan_resolution=64)


@pytest.fixture(scope="session")
def tiny_data(tmp_path_factory):
    out = tmp_path_factory.mktemp("tiny_data")
    tasks = procedural_tasks(6, categories=("chair", "table", "airplane"))
    build_dataset(out, tasks, TINY, workers=1, progress=False)
    return out


SCANS = BuildConfig(depth=5, views=1, render_size=32, partial_scans=2, scan_resolution=64)


@pytest.fixture(scope="session")
def scan_data(tmp_path_factory):
    """Two categories with two partial scans per shape (the completion task's input)."""
    out = tmp_path_factory.mktemp("scan_data")
    build_dataset(out, procedural_tasks(5, categories=("chair", "airplane")), SCANS, workers=1, progress=False)
    return out
