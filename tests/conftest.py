"""Options of the whole suite.

``AOCNN_PERTURB_KERNELS=<relative>`` (e.g. 1e-5) runs every test with onnxruntime's outputs
perturbed as another CPU's kernels would change them (:mod:`tests.kernels`): what passes so
does not depend on the instruction set of the machine it runs on.
"""

from __future__ import annotations

import os

import pytest


@pytest.fixture(scope="session", autouse=True)
def _perturbed_kernels_when_asked():
    relative = os.environ.get("AOCNN_PERTURB_KERNELS")
    if not relative:
        yield
        return
    from .kernels import perturbed_kernels

    with perturbed_kernels(float(relative)):
        yield
