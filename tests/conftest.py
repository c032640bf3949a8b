"""Options and shared data of the whole suite.

``AOCNN_PERTURB_KERNELS=<relative>`` (e.g. 1e-5) runs every test with onnxruntime's outputs
perturbed as another CPU's kernels would change them (:mod:`tests.kernels`): what passes so
does not depend on the instruction set of the machine it runs on.
"""

from __future__ import annotations

import os

import pytest

from model.data.dataset import BuildConfig, build_dataset, procedural_tasks


@pytest.fixture(scope="session", autouse=True)
def _perturbed_kernels_when_asked():
    relative = os.environ.get("AOCNN_PERTURB_KERNELS")
    if not relative:
        yield
        return
    from .kernels import perturbed_kernels

    with perturbed_kernels(float(relative)):
        yield


# A tiny procedural dataset shared by the network, training and research tests.
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
