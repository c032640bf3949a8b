"""The export's checks do not depend on the CPU they run on: with onnxruntime's outputs changed as
another instruction set's kernels change them (:mod:`tests.kernels`: relative 1e-5 on float32
outputs, one quantisation step on int8 ones), every check of every shipped bundle passes, and
real defects (a wrong weight, a transposed plane, a gather off by one, a wrong int8 weight) still
fail, named."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
import torch

from bench.int8_cpus import run_here_and_on_avx2
from export.__main__ import main as export_main
from export.__main__ import verify, verify_against
from export.bundle import BundleError
from export.exporter import foreground_photos, load_foreground, load_source, self_check
from export.runtime import Runtime

from ..kernels import perturb, perturbed_kernels

MODELS = Path(__file__).resolve().parents[2] / "models"
SHIPPED = {"image-to-shape": "foreground", "completion": None, "classify": None}
"""Bundle -> the foreground checkpoint it carries."""


def _against(name: str) -> dict:
    fg = SHIPPED[name]
    return verify_against(str(MODELS / "bundles" / name), str(MODELS / "checkpoints" / name),
                          None if fg is None else str(MODELS / "checkpoints" / fg))


def test_perturbation_changes_outputs_as_other_kernels_do():
    x = np.random.default_rng(0).normal(0, 10, 10_000).astype(np.float32)
    y = perturb(x, 1e-5)
    change = np.abs(y - x) / np.abs(x)
    assert 0.4e-5 < float(np.mean(change)) < 0.6e-5 and float(change.max()) <= 1.01e-5     # to float32 rounding
    assert np.array_equal(perturb(x, 1e-5), y)                  # a fixed function of the value, as kernels are
    assert np.mean(y > x) == pytest.approx(0.5, abs=0.03)


@pytest.mark.parametrize("name", sorted(SHIPPED))
def test_every_shipped_bundle_verifies_and_matches_torch_under_other_kernels(name):
    """--verify and --against (the export's own check) on the shipped bundles, perturbed: the figures
    stay within the tolerance, int8 masks included."""
    plain = _against(name)
    with perturbed_kernels(1e-5, int8_steps=1):
        assert verify(str(MODELS / "bundles" / name))["graphs"] > 1
        check = _against(name)
    assert check["max_relative_error"] <= check["relative_tolerance"] / 2
    assert check["max_relative_error"] > plain["max_relative_error"]          # the perturbation was applied
    if SHIPPED[name]:
        assert check["foreground_int8_steps_p99"] <= plain["foreground_int8_steps_p99"] + 1.01
        assert check["foreground_pixel_agreement"] >= 0.99


def test_the_verify_command_checks_a_guided_bundle_with_and_without_torch(capsys):
    bundle = str(MODELS / "bundles" / "completion")
    assert export_main(["--verify", bundle]) == 0
    assert export_main(["--verify", bundle, "--against", str(MODELS / "checkpoints" / "completion")]) == 0
    out = capsys.readouterr().out
    assert "decoded" in out and "outputs within" in out and "whole decodes" in out
    # the wrong checkpoint: one line, exit status 2
    assert export_main(["--verify", bundle, "--against", str(MODELS / "checkpoints" / "image-to-shape")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err
    assert export_main(["--verify", str(MODELS / "bundles" / "image-to-shape"), "--against",
                        str(MODELS / "checkpoints" / "image-to-shape")]) == 2
    assert "--foreground" in capsys.readouterr().err


def _completion():
    return MODELS / "bundles" / "completion", load_source(MODELS / "checkpoints" / "completion")


def test_a_wrong_weight_fails_the_check_naming_the_graph():
    folder, src = _completion()
    with torch.no_grad():
        src.model.decoder.pred["5"][-1].weight[0] += 0.05             # one status weight of depth 5
    with perturbed_kernels(), pytest.raises(BundleError, match=r"decoder_predict_5/logits differs by"):
        self_check(folder, src)


def _altered(graph: str, change):
    """:meth:`Runtime.run` with ``graph``'s run replaced by ``change(runtime, feeds, real_run)``."""
    real = Runtime.run

    def run(self, name, feeds):
        return real(self, name, feeds) if name != graph else change(self, feeds, real)

    return run


def test_a_transposed_plane_and_an_off_by_one_gather_fail_the_check():
    folder, src = _completion()

    def transposed(runtime, feeds, real):
        out = real(runtime, "decoder_predict_6", feeds)
        out[2] = out[2][:, [1, 0, 2, 3]]
        return out

    def off_by_one(runtime, feeds, real):
        nb = feeds["neighbors"]
        return real(runtime, "decoder_predict_4", {**feeds, "neighbors": np.where(nb >= 1, nb - 1, nb)})

    for graph, change, output in (("decoder_predict_6", transposed, "decoder_predict_6/planes"),
                                  ("decoder_predict_4", off_by_one, "decoder_predict_4/features")):
        with pytest.MonkeyPatch.context() as mp:
            mp.setattr(Runtime, "run", _altered(graph, change))
            with pytest.raises(BundleError, match=f"{output} differs by"):
                self_check(folder, src)


def test_a_wrong_int8_foreground_weight_fails_and_one_step_does_not():
    folder = MODELS / "bundles" / "image-to-shape"
    src, fg = load_source(MODELS / "checkpoints" / "image-to-shape"), load_foreground(MODELS / "checkpoints" / "foreground")
    photos = foreground_photos(fg.config.image_size)[1]
    with perturbed_kernels(1e-5, int8_steps=1):
        self_check(folder, src, foreground=fg, foreground_inputs=photos, foreground_precision="int8")
    head = [m for m in fg.model.net.modules() if isinstance(m, torch.nn.Conv2d)][-1]
    with torch.no_grad():
        head.bias += 3.0                                            # every logit 3 higher: 20 quantisation steps
    with pytest.raises(BundleError, match="quantisation steps"):
        self_check(folder, src, foreground=fg, foreground_inputs=photos, foreground_precision="int8")


def test_the_shipped_int8_foreground_network_gives_the_same_logits_without_vnni(tmp_path):
    """The shipped int8 graph run here and under qemu's Haswell (AVX2, no VNNI: onnxruntime's u8s8
    kernels add pairs of products in saturating 16 bits there, as the probe shows): the same logits
    bit for bit, since its 7-bit weights keep every pair within 16 bits."""
    if shutil.which("qemu-x86_64") is None:
        pytest.skip("needs qemu-user (apt-get install qemu-user) to run onnxruntime's AVX2 kernels")
    shutil.copy(MODELS / "bundles" / "image-to-shape" / "foreground.onnx", tmp_path / "foreground.onnx")
    np.save(tmp_path / "inputs.npy", np.concatenate(foreground_photos(128)[1][:4]))
    run_here_and_on_avx2(tmp_path)
    assert json.loads((tmp_path / "probe.avx2.json").read_text())["u8s8_dot"] < 255 * 127 * 64     # saturates
    native, avx2 = (np.load(tmp_path / f"foreground.{tag}.npy") for tag in ("native", "avx2"))
    assert native.shape == (4, 1, 128, 128) and np.array_equal(native, avx2)
