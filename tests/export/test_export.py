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
from export.runtime import Runtime
from model.decode import decode
from model.networks import ARCHS, TorchSteps
from model.nn.tensors import OctreeTensors
from model.octree import LEAF, build_octree
from model.octree.batch import split_octree
from model.octree.metrics import sample_patches
from model.octree.patches import patches_to_mesh
from model.preprocess import prepare_image

from .conftest import octree_batch

TOL = 1e-4
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
    assert np.abs(latent_o - latent_t.numpy()).max() <= TOL

    # each decoder step, teacher-forced along the true octree, from the same inputs
    dec, steps = model.decoder, runtime.steps()
    with torch.no_grad():
        x_t = dec.start(latent_t)
    x_o = steps.start(latent_t.numpy())
    assert np.abs(x_o - x_t.numpy()).max() <= TOL
    for d in range(dec.full_depth, dec.depth + 1):
        lv = tensors.levels[d]
        with torch.no_grad():
            y_t, logits_t, plane_t = dec.predict(d, torch.from_numpy(x_o), lv.neighbors)
        y_o, logits_o, plane_o = steps.predict(d, x_o, truth.levels[d].neighbors)
        assert np.abs(y_o - y_t.numpy()).max() <= TOL
        assert np.abs(logits_o - logits_t.numpy()).max() <= TOL
        assert (plane_o is None) == (plane_t is None)
        if plane_o is not None:
            assert np.abs(plane_o - plane_t.numpy()).max() <= TOL
        if d < dec.depth:
            with torch.no_grad():
                x_t = dec.expand(d, torch.from_numpy(y_o), lv.split)
            x_o = steps.expand(d, y_o, truth.levels[d].split_nodes())
            assert x_o.shape == tuple(x_t.shape)
            assert np.abs(x_o - x_t.numpy()).max() <= TOL


@pytest.mark.parametrize("name", ["aocnn", "ocnn-patch-star"])
def test_decoding_through_onnxruntime_grows_the_same_octree(exported, clouds, name):
    model, cfg, folder = exported(name)
    runtime = Runtime(load_bundle(folder), threads=1)
    latent = runtime.encode_octree(_truth(model, cfg, clouds, start=1))
    a = runtime.decode(latent)
    b = decode(TorchSteps(model.decoder), latent, model.decoder.full_depth, model.decoder.adaptive_depth)
    same = total = 0
    for la, lb in zip(a.levels, b.levels):
        total += len(lb)
        if np.array_equal(la.key, lb.key):
            same += int(np.sum(la.label == lb.label))
    assert total > 1000 and same / total >= 0.999
    # a split logit within rounding of zero may decide differently (a random-weight decoder has many):
    # leaves may differ by 0.5%,
    # and the leaves both decoded carry the same patches
    leaves_a, leaves_b = _leaves(a), _leaves(b)
    common = sorted(set(leaves_a) & set(leaves_b))
    assert len(common) > 100 and len(set(leaves_a) ^ set(leaves_b)) <= 0.005 * len(leaves_b)
    pa, pb = np.array([leaves_a[k] for k in common]), np.array([leaves_b[k] for k in common])
    assert np.abs(pa - pb).max() <= TOL
    assert len(patches_to_mesh(a, world=False).faces) > 0


def _leaves(octree) -> dict:
    """(depth, key) -> plane of every leaf."""
    return {(lv.depth, int(k)): p for lv in octree.levels
            for k, p in zip(lv.key[lv.label == LEAF], lv.plane[lv.label == LEAF].astype(np.float64))}


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


class _Lockstep:
    """torch's and onnxruntime's decoder steps driven through one octree, its structure torch's:
    each step of onnxruntime gets its own features, and its outputs are compared with torch's.  An
    untrained decoder (the fixtures' biases put about half its octants near a tie) has status logits
    within float error of a tie, which can make two decodes' octrees differ on another machine while
    every graph agrees; in lockstep the graphs are compared, not the tie-breaking."""

    def __init__(self, model, runtime):
        self.torch, self.ort = TorchSteps(model.decoder), runtime.steps()
        self.depth, self.compared = self.torch.depth, 0

    def classes(self, depth):
        return self.torch.classes(depth)

    def _agree(self, t, o):
        t = t.numpy() if isinstance(t, torch.Tensor) else np.asarray(t)
        assert t.shape == o.shape and np.abs(t - o).max() <= TOL * max(1.0, float(np.abs(t).max()))
        self.compared += 1

    def start(self, latent):
        features = self.torch.start(latent), self.ort.start(latent)
        self._agree(*features)
        return features

    def predict(self, depth, features, neighbors, *skip):
        xt, logits, planes = self.torch.predict(depth, features[0], neighbors, *skip)
        xo, logits_o, planes_o = self.ort.predict(depth, features[1], neighbors, *skip)
        for t, o in ((xt, xo), (logits, logits_o), (planes, planes_o)):
            if t is not None:
                self._agree(t, o)
        return (xt, xo), logits, planes

    def expand(self, depth, features, split):
        children = self.torch.expand(depth, features[0], split), self.ort.expand(depth, features[1], split)
        self._agree(*children)
        return children


def _decoders_agree(model, runtime, latent):
    """onnxruntime's decoder graphs give torch's outputs at every step of a decode of ``latent``
    (:class:`_Lockstep`), which grows octrees with patches; the bundle decodes it too."""
    steps = _Lockstep(model, runtime)
    octrees = split_octree(decode(steps, latent, 2, 4))
    assert steps.compared >= 3 * (model.decoder.depth - 2)
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
    assert np.abs(latent_o - latent_t).max() <= TOL
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
    assert np.abs(latent_o - latent_t).max() <= TOL
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
    assert np.abs(latent_o - latent_t.numpy()).max() <= TOL
    assert sorted(guide_o.features) == list(range(2, cfg.depth + 1))
    for d, f in guide_o.features.items():
        assert f.shape == (len(truth.levels[d]), model.encoder.channels[d])
        assert np.abs(f - guide_t.features[d].numpy()).max() <= TOL
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
        assert np.abs(y_o - y_t.numpy()).max() <= TOL and np.abs(logits_o - logits_t.numpy()).max() <= TOL
        assert float((y_t - y_plain).abs().max()) > 1e-3     # the skip features change the features
        if d < dec.depth:
            x = steps.expand(d, y_o, truth.levels[d].split_nodes())

    a = runtime.decode(latent_o, guide=guide_o)
    b = decode(TorchSteps(dec), latent_t.numpy(), dec.full_depth, dec.adaptive_depth, guide=guide_t)
    leaves_a, leaves_b = _leaves(a), _leaves(b)
    assert len(leaves_b) > 100 and len(set(leaves_a) ^ set(leaves_b)) <= 0.005 * len(leaves_b)
    with pytest.raises(ValueError, match="guide"):
        runtime.decode(latent_o)
    # the guide of the second and third shapes decodes them as in the batch
    sub = runtime.decode(latent_o[1:], guide=guide_o.subset(np.array([1, 2])))
    whole = split_octree(a, neighbors=False)
    for tree, ref in zip(split_octree(sub, neighbors=False), whole[1:]):
        assert [len(lv) for lv in tree.levels] == [len(lv) for lv in ref.levels]
        assert all(np.array_equal(x.label, y.label) for x, y in zip(tree.levels, ref.levels))
