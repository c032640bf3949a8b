"""Export parity: every ONNX graph against torch eval mode on real octrees, batch > 1; decoding
through onnxruntime grows the same octree; graphs use standard operators only."""

from __future__ import annotations

import numpy as np
import onnx
import pytest
import torch
from PIL import Image

from export.bundle import load_bundle
from export.fold import fold_batchnorm
from export.parity import RELATIVE_TOLERANCE, decoder_parity, leaf_planes, relative_error
from export.runtime import Runtime
from model.image.frame import prepare_image
from model.networks import ARCHS, TorchSteps
from model.nn.tensors import OctreeTensors
from model.octree import build_octree
from model.octree.batch import split_octree
from model.octree.metrics import sample_patches
from model.octree.patches import patches_to_mesh

from .conftest import octree_batch

TOL = RELATIVE_TOLERANCE
STANDARD_OPS = {"Gather", "MatMul", "Gemm", "Reshape", "ScatterND", "ScatterElements", "ReduceMax", "Max",
                "Relu", "Tanh", "Add", "Mul", "Div", "Sub", "Concat", "Shape", "Slice", "Expand", "Unsqueeze",
                "ConstantOfShape", "Constant", "Clip", "ReduceL2", "Conv", "MaxPool", "GlobalAveragePool",
                "ReduceMean", "Flatten", "Transpose", "Squeeze", "Identity", "Cast", "Sqrt", "Pow"}
OCTREE_ARCHS = ["aocnn", "ocnn-patch-star", "ocnn-patch", "ocnn-binary"]


def _truth(model, cfg, clouds, start=0):
    adaptive = ARCHS[cfg.arch].octree == "adaptive"
    return octree_batch(clouds, cfg.depth, adaptive, batch=3, start=start)


@pytest.mark.parametrize("name", OCTREE_ARCHS)
def test_every_graph_matches_torch_on_real_octrees(exported, clouds, name):
    model, cfg, folder = exported(name)
    runtime = Runtime(load_bundle(folder), threads=1)
    truth = _truth(model, cfg, clouds)
    tensors = OctreeTensors.from_octree(truth)
    with torch.no_grad():
        latent_t = model.encoder(tensors)
    latent_o = runtime.encode_octree(truth)
    assert latent_o.shape == (3, cfg.latent)
    assert relative_error(latent_t.numpy(), latent_o) <= TOL

    # each decoder step, teacher-forced along the true octree, from the same inputs
    dec, steps = model.decoder, runtime.steps()
    with torch.no_grad():
        x_t = dec.start(latent_t)
    x_o = steps.start(latent_t.numpy())
    assert relative_error(x_t.numpy(), x_o) <= TOL
    for d in range(dec.full_depth, dec.depth + 1):
        lv = tensors.levels[d]
        with torch.no_grad():
            y_t, logits_t, plane_t = dec.predict(d, torch.from_numpy(x_o), lv.neighbors)
        y_o, logits_o, plane_o = steps.predict(d, x_o, truth.levels[d].neighbors)
        assert relative_error(y_t.numpy(), y_o) <= TOL
        assert relative_error(logits_t.numpy(), logits_o) <= TOL
        assert (plane_o is None) == (plane_t is None)
        if plane_o is not None:
            assert relative_error(plane_t.numpy(), plane_o) <= TOL
        if d < dec.depth:
            with torch.no_grad():
                x_t = dec.expand(d, torch.from_numpy(y_o), lv.split)
            x_o = steps.expand(d, y_o, truth.levels[d].split_nodes())
            assert x_o.shape == tuple(x_t.shape)
            assert relative_error(x_t.numpy(), x_o) <= TOL


@pytest.mark.parametrize("name", OCTREE_ARCHS)
def test_decoding_through_onnxruntime_matches_torch_step_by_step(exported, clouds, name):
    """A decode in lockstep (export.parity): torch's statuses grow the octree, onnxruntime runs
    every step on the same octants, and every output agrees within the cross-CPU tolerance.  The
    fixtures' random decoders put many statuses near a tie, so whole decodes are compared only as
    a statistic (they may grow different octrees on another CPU while every graph agrees)."""
    model, cfg, folder = exported(name)
    runtime = Runtime(load_bundle(folder), threads=1)
    latent = runtime.encode_octree(_truth(model, cfg, clouds, start=1))
    dec = model.decoder
    report, tree = decoder_parity(TorchSteps(dec), runtime.steps(), latent, dec.full_depth, dec.adaptive_depth)
    assert report.ok, report.summary()
    graphs = {name for name in load_bundle(folder).graphs if name.startswith("decoder_")}
    assert {step.name.split("/")[0] for step in report.steps} == graphs          # every decoder graph compared
    assert report.nodes > 1000 and 0.0 <= report.label_agreement <= 1.0      # ties: reported, not checked
    assert 0.0 <= report.decode_label_agreement <= 1.0
    if dec.has_plane(dec.depth):
        assert len(patches_to_mesh(tree, world=False).faces) > 0


def test_graphs_use_standard_operators_only_with_dynamic_sizes_and_folded_batch_norm(exported):
    _, _, folder = exported("aocnn")
    bundle = load_bundle(folder)
    for name in bundle.graphs:
        proto = onnx.load(str(bundle.file(name)))
        onnx.checker.check_model(proto, full_check=True)
        assert {o.domain for o in proto.opset_import} <= {"", "ai.onnx"}
        assert max(o.version for o in proto.opset_import if o.domain in ("", "ai.onnx")) >= 18
        ops = {n.op_type for n in proto.graph.node}
        assert ops <= STANDARD_OPS, f"{name}: {ops - STANDARD_OPS}"
        assert all(n.domain in ("", "ai.onnx") for n in proto.graph.node)
        assert "BatchNormalization" not in ops
        first = proto.graph.input[0].type.tensor_type.shape.dim[0]
        assert first.dim_param and not first.dim_value, f"{name}: first axis is not dynamic"
    assert {"Gather", "Gemm"} <= {n.op_type for n in onnx.load(str(bundle.file("decoder_predict_5"))).graph.node}
    encoder_ops = {n.op_type for n in onnx.load(str(bundle.file("octree_encoder"))).graph.node}
    assert {"ReduceMax", "ScatterND", "Gather"} <= encoder_ops


def test_batch_norm_folding_keeps_every_network_s_outputs(exported, clouds):
    model, cfg, _ = exported("aocnn")
    truth = _truth(model, cfg, clouds)
    t = OctreeTensors.from_octree(truth)
    folded = fold_batchnorm(model)
    assert not any(isinstance(m, torch.nn.modules.batchnorm._BatchNorm) for m in folded.modules())
    with torch.no_grad():
        assert torch.allclose(folded.encoder(t), model.encoder(t), atol=1e-5)
        for (la, pa), (lb, pb) in zip(folded.decoder(model.encoder(t), t), model.decoder(model.encoder(t), t)):
            assert torch.allclose(la, lb, atol=1e-4)
            assert (pa is None and pb is None) or torch.allclose(pa, pb, atol=1e-5)


def _photo(seed: int) -> Image.Image:
    """A synthetic photo: a shaded object on a textured background."""
    rng = np.random.default_rng(seed)
    img = (rng.uniform(150, 255, (96, 120, 3))).astype(np.uint8)
    img[20:80, 30:90] = rng.integers(0, 120, 3)
    img[35:60, 45:70] = 30
    return Image.fromarray(img)


def _decoders_agree(model, runtime, latent):
    """onnxruntime's decoder graphs give torch's outputs at every step of a decode of ``latent``
    (:class:`export.parity.Lockstep`), which grows octrees with patches; the bundle decodes it too."""
    report, tree = decoder_parity(TorchSteps(model.decoder), runtime.steps(), latent, 2, 4)
    assert report.ok, report.summary()
    octrees = split_octree(tree)
    assert len(report.steps) >= 3 * (model.decoder.depth - 2)
    assert all(len(sample_patches(o, 64, seed=0)) > 100 for o in octrees)
    assert sum(runtime.decode(latent).leaves_per_depth()) > 0


def test_image_to_shape_end_to_end_matches_torch(exported):
    model, cfg, folder = exported("image-resnet18")
    bundle = load_bundle(folder)
    assert bundle.task == "image-to-shape" and bundle.input["image"]["size"] == cfg.image_size
    runtime = Runtime(bundle, threads=1)
    spec = bundle.image_spec()
    images = np.stack([prepare_image(_photo(s), spec) for s in range(3)])
    latent_o = runtime.encode_image(images)
    with torch.no_grad():
        latent_t = model.encoder(torch.from_numpy(images)).numpy()
    assert relative_error(latent_t, latent_o) <= TOL
    _decoders_agree(model, runtime, latent_t)


def test_completion_end_to_end_matches_torch(exported, clouds):
    """A partial cloud (a slab cut away) -> octree -> encoder -> decoder, onnxruntime vs torch."""
    model, cfg, folder = exported("aocnn")
    runtime = Runtime(load_bundle(folder), threads=1)
    pts, nrm = clouds[-1]
    keep = pts[:, 0] < np.quantile(pts[:, 0], 0.6)
    octree = build_octree((pts[keep], None), cfg.depth)          # normals estimated, as the service does
    latent_o = runtime.encode_octree(octree)
    with torch.no_grad():
        latent_t = model.encoder(OctreeTensors.from_octree(octree)).numpy()
    assert relative_error(latent_t, latent_o) <= TOL
    _decoders_agree(model, runtime, latent_t)


def test_a_level_where_nothing_splits_runs(exported, tmp_path):
    """No octant is non-empty at depth 3: the loop stops, and the graphs run on 0 rows."""
    from export.exporter import export

    from .conftest import make_model, save_checkpoint

    model, cfg = make_model("aocnn")
    with torch.no_grad():
        model.decoder.pred["3"][-1].bias[1] = -1e4         # depth 3 has 2 classes: never non-empty
    save_checkpoint(model, cfg, tmp_path / "ckpt")
    export(tmp_path / "ckpt", tmp_path / "bundle")
    runtime = Runtime(load_bundle(tmp_path / "bundle"), threads=1)
    octree = runtime.decode(np.zeros((2, cfg.latent), np.float32))
    sizes = [len(lv) for lv in octree.levels]
    assert sizes[3] > 0 and sizes[4:] == [0, 0] and sum(octree.leaves_per_depth()) == 0
    steps = runtime.steps()
    empty = steps.expand(3, np.zeros((5, model.decoder.channels[3]), np.float32), np.zeros(0, np.int64))
    assert empty.shape == (0, model.decoder.channels[4])
    y, logits, planes = steps.predict(4, empty, np.zeros((0, 27), np.int64))
    assert y.shape[0] == logits.shape[0] == planes.shape[0] == 0


def test_a_coarser_level_of_detail_stops_at_the_requested_depth(exported, clouds):
    model, cfg, folder = exported("aocnn")
    runtime = Runtime(load_bundle(folder), threads=1)
    latent = runtime.encode_octree(_truth(model, cfg, clouds))
    coarse = runtime.decode(latent, depth=4)
    assert coarse.depth == 4 and len(coarse.levels) == 5 and sum(coarse.leaves_per_depth()) > 0
    with pytest.raises(ValueError, match="depth must be in 2..5"):
        runtime.decode(latent, depth=6)


def test_guided_graphs_pass_the_encoder_features_and_match_torch(exported, clouds):
    """Output-guided skip connections in the graphs: the encoder outputs every depth's features,
    each predict step adds the input's features at the octants it shares (by key), and decoding
    through onnxruntime grows the octree torch grows."""
    model, cfg, folder = exported("completion-guided")
    bundle = load_bundle(folder)
    assert bundle.octree.guided and bundle.format == 2
    runtime = Runtime(bundle, threads=1)
    truth = _truth(model, cfg, clouds, start=2)
    latent_o, guide_o = runtime.encode_scan(truth)
    with torch.no_grad():
        latent_t, guide_t = model.encode_octree(truth)
    assert relative_error(latent_t.numpy(), latent_o) <= TOL
    assert sorted(guide_o.features) == list(range(2, cfg.depth + 1))
    for d, f in guide_o.features.items():
        assert f.shape == (len(truth.levels[d]), model.encoder.channels[d])
        assert relative_error(guide_t.features[d].numpy(), f) <= TOL
        assert np.array_equal(guide_o.keys[d], truth.levels[d].key)

    # teacher forcing along the input's own octree: every octant is found in the guide
    dec, steps = model.decoder, runtime.steps()
    x = steps.start(latent_o)
    for d in range(dec.full_depth, dec.depth + 1):
        rows = guide_o.rows(d, truth.levels[d].key)
        assert np.array_equal(rows, np.arange(len(truth.levels[d])))
        nb = truth.levels[d].neighbors
        y_o, logits_o, _ = steps.predict(d, x, nb, guide_o.features[d], rows)
        with torch.no_grad():
            y_t, logits_t, _ = dec.predict(d, torch.from_numpy(x), torch.from_numpy(nb.astype(np.int64)),
                                           guide_t.features[d], torch.from_numpy(rows))
            y_plain = dec.conv[str(d)](torch.from_numpy(x), torch.from_numpy(nb.astype(np.int64)))
        assert relative_error(y_t.numpy(), y_o) <= TOL and relative_error(logits_t.numpy(), logits_o) <= TOL
        assert float((y_t - y_plain).abs().max()) > 1e-3     # the skip features change the features
        if d < dec.depth:
            x = steps.expand(d, y_o, truth.levels[d].split_nodes())

    # the whole decode in lockstep, each implementation reading its own encoder's features
    report, b = decoder_parity(TorchSteps(dec), steps, latent_t.numpy(), dec.full_depth, dec.adaptive_depth,
                               other_latent=latent_o, guides=(guide_t, guide_o))
    assert report.ok, report.summary()
    assert len(leaf_planes(b)) > 100
    a = runtime.decode(latent_o, guide=guide_o)
    with pytest.raises(ValueError, match="guide"):
        runtime.decode(latent_o)
    # the guide of the second and third shapes decodes them as in the batch
    sub = runtime.decode(latent_o[1:], guide=guide_o.subset(np.array([1, 2])))
    whole = split_octree(a, neighbors=False)
    for tree, ref in zip(split_octree(sub, neighbors=False), whole[1:]):
        assert [len(lv) for lv in tree.levels] == [len(lv) for lv in ref.levels]
        assert all(np.array_equal(x.label, y.label) for x, y in zip(tree.levels, ref.levels))
