"""The ONNX graphs of a trained model: one per step the service runs, BN folded, dynamic sizes.

Graphs and their inputs/outputs (names as in :mod:`export.bundle`'s spec):

- ``image_encoder``: image (B, 3, S, S) -> latent (B, L).
- ``octree_encoder``: per depth d of the encoder, signal_d (N_d, 4), neighbors_d (N_d, 27) int64,
  and split_d (K_d,) int64 for d < depth -> latent (B, L) [, skip_d (N_d, C_d) per depth d when
  the decoder is guided].
- ``decoder_start``: latent (B, L) -> features (64 B, C).
- ``decoder_predict_d``: features (N, C), neighbors (N, 27) int64 [, skip (M, C) the input's
  features and skip_index (N,) int64 each octant's row in them, M for none: guided decoders]
  -> features (N, C), logits (N, classes) [, planes (N, 4)].
- ``decoder_expand_d``: features (N, C), split (K,) int64 -> features (8 K, C').

Index tables come from the NumPy octree core; no graph derives them.  Octree ops are
Gather + MatMul (Gemm) + ReduceMax + ScatterND (see :mod:`model.nn.ops`).  Exported with the TorchScript-based
exporter (``dynamo=False``): see :data:`EXPORTER`.
"""

from __future__ import annotations

import contextlib
import io
import logging
import warnings
from dataclasses import dataclass

import torch
from torch import nn

from model.networks import OctreeDecoder, OctreeEncoder
from model.nn.ops import KERNEL

from .fold import fold_batchnorm

OPSET = 18
EXPORTER = "dynamo"
"""torch.onnx.export(dynamo=True), chosen over the TorchScript-based exporter (dynamo=False).
Both export these graphs and run them equally fast in onnxruntime (docs/export.md); the
TorchScript one is deprecated in torch 2.13 ("will be removed") and writes 2-4x more nodes (its
scatter symbolic adds If/Squeeze branches); the dynamo one needs the size relations declared
(N_{d+1} = 8 K_d, N_2 = 64 B), which it checks against the code: a wrong relation fails at export."""


@dataclass
class Graph:
    """One exported graph: its role, its ONNX bytes, and its input/output names and shapes."""

    name: str
    model: bytes
    inputs: dict[str, tuple]       # name -> (dtype, shape with str for dynamic axes)
    outputs: dict[str, tuple]


class _Start(nn.Module):
    def __init__(self, decoder: OctreeDecoder):
        super().__init__()
        self.decoder = decoder

    def forward(self, latent):
        return self.decoder.start(latent)


class _Predict(nn.Module):
    def __init__(self, decoder: OctreeDecoder, depth: int):
        super().__init__()
        self.decoder, self.depth = decoder, depth

    def forward(self, features, neighbors):
        return self.outputs(features, neighbors)

    def outputs(self, *args):
        x, logits, plane = self.decoder.predict(self.depth, *args)
        return (x, logits) if plane is None else (x, logits, plane)


class _GuidedPredict(_Predict):
    def forward(self, features, neighbors, skip, skip_index):
        return self.outputs(features, neighbors, skip, skip_index)


class _Expand(nn.Module):
    def __init__(self, decoder: OctreeDecoder, depth: int):
        super().__init__()
        self.decoder, self.depth = decoder, depth

    def forward(self, features, split):
        return self.decoder.expand(self.depth, features, split)


class _Encoder(nn.Module):
    def __init__(self, encoder: OctreeEncoder, guided: bool = False):
        super().__init__()
        self.encoder, self.guided = encoder, guided
        self.depths = list(range(encoder.full_depth, encoder.depth + 1))

    def forward(self, *tables):
        signals, neighbors, splits = {}, {}, {}
        it = iter(tables)
        for d in self.depths:
            if self.uses_signal(d):
                signals[d] = next(it)
            neighbors[d] = next(it)
            if d < self.encoder.depth:
                splits[d] = next(it)
        latent, features = self.encoder.encode_features(signals, neighbors, splits)
        return (latent, *(features[d] for d in self.depths)) if self.guided else latent

    def uses_signal(self, d: int) -> bool:
        return self.encoder.signal == "all" or d == self.encoder.depth


def _dims(shape: tuple, dims: dict) -> dict:
    """torch.export dynamic dims of one input: "name" or "k*name" axes (k an int factor)."""
    out = {}
    for i, axis in enumerate(shape):
        if isinstance(axis, str):
            factor, _, name = axis.rpartition("*")
            dim = dims.setdefault(name, torch.export.Dim(name))
            out[i] = int(factor) * dim if factor else dim
    return out


def _export(module: nn.Module, args: tuple, inputs: dict[str, tuple], outputs: dict[str, tuple]) -> bytes:
    """ONNX bytes of ``module`` on example ``args``; str axes of the input shapes are dynamic."""
    dims: dict = {}
    shapes = tuple(_dims(shape, dims) for _, shape in inputs.values())
    if isinstance(module, _Encoder):             # forward(*tables): one group of inputs
        shapes = (shapes,)
    quiet = logging.getLogger("torch.onnx")
    level = quiet.level
    with warnings.catch_warnings(), contextlib.redirect_stdout(io.StringIO()):
        warnings.simplefilter("ignore")
        quiet.setLevel(logging.ERROR)
        program = torch.onnx.export(module.eval(), args, input_names=list(inputs), output_names=list(outputs),
                                    dynamic_shapes=shapes, opset_version=OPSET, dynamo=True,
                                    external_data=False, verbose=False)
        quiet.setLevel(level)
    proto = program.model_proto
    for value, (_, shape) in zip(proto.graph.output, outputs.values()):   # name the output axes as the spec
        for dim, axis in zip(value.type.tensor_type.shape.dim, shape):
            if isinstance(axis, str):
                dim.dim_param = axis
    strip_debug_info(proto)
    return proto.SerializeToString()


def strip_debug_info(proto) -> None:
    """Remove what the exporter records about the machine that ran it: each node's source stack
    trace (absolute paths of this checkout and of site-packages), FX names and scopes, and the
    exported program's signatures.  What remains is the graph itself, so the same checkpoint
    exported with the same package versions gives the same bytes on any machine."""
    graph = proto.graph
    for items in (graph.node, graph.value_info, graph.input, graph.output, graph.initializer):
        for item in items:
            del item.metadata_props[:]
            item.doc_string = ""
    del graph.metadata_props[:]
    del proto.metadata_props[:]
    graph.doc_string = proto.doc_string = ""


def _table(n: int, generator: torch.Generator) -> torch.Tensor:
    """An example neighbour table (values only matter for tracing, not for the graph)."""
    return torch.randint(-1, n, (n, KERNEL), generator=generator)


def _graph(name: str, module: nn.Module, args: tuple, inputs: dict, outputs: dict) -> Graph:
    return Graph(name, _export(module, args, inputs, outputs), inputs, outputs)


def decoder_graphs(decoder: OctreeDecoder, latent: int) -> list[Graph]:
    """start, predict_d and expand_d graphs of an octree decoder (BN folded)."""
    dec = fold_batchnorm(decoder)
    g = torch.Generator().manual_seed(0)
    ch = dec.channels
    z = torch.rand(2, latent, generator=g) * 2 - 1
    graphs = [_graph("decoder_start", _Start(dec), (z,), {"latent": ("float32", ("batch", latent))},
                     {"features": ("float32", ("64*batch", ch[dec.full_depth]))})]
    for d in range(dec.full_depth, dec.depth + 1):
        n = 128
        x = torch.rand(n, ch[d], generator=g)
        outs = {"features_out": ("float32", ("nodes", ch[d])), "logits": ("float32", ("nodes", dec.classes(d)))}
        if dec.has_plane(d):
            outs["planes"] = ("float32", ("nodes", 4))
        ins = {"features": ("float32", ("nodes", ch[d])), "neighbors": ("int64", ("nodes", KERNEL))}
        args = (x, _table(n, g))
        if dec.guided:        # the input's features at this depth, and each octant's row in them (M: none)
            ins.update(skip=("float32", ("inputs", ch[d])), skip_index=("int64", ("nodes",)))
            args += (torch.rand(96, ch[d], generator=g), torch.randint(0, 97, (n,), generator=g))
        graphs.append(_graph(f"decoder_predict_{d}", (_GuidedPredict if dec.guided else _Predict)(dec, d),
                             args, ins, outs))
        if d < dec.depth:
            graphs.append(_graph(f"decoder_expand_{d}", _Expand(dec, d), (x, torch.tensor([0, 3, 5, 100])),
                                 {"features": ("float32", ("nodes", ch[d])), "split": ("int64", ("splits",))},
                                 {"children": ("float32", ("8*splits", ch[d + 1]))}))
    return graphs


def encoder_graph(encoder: OctreeEncoder, latent: int, guided: bool = False) -> Graph:
    """The octree encoder on per-depth tables (BN folded); N_2 = 64 B, N_{d+1} = 8 K_d.  ``guided``:
    it also outputs the features of every depth's octants (skip_d, for a guided decoder)."""
    wrapper = _Encoder(fold_batchnorm(encoder), guided)
    full, depth = wrapper.encoder.full_depth, wrapper.encoder.depth
    g = torch.Generator().manual_seed(0)
    ins, args = {}, []
    n = {d: 128 << (d - full) for d in wrapper.depths}           # 2 shapes, a quarter of octants split
    for d in wrapper.depths:
        nodes = "64*batch" if d == full else f"8*splits_{d - 1}"
        if wrapper.uses_signal(d):
            ins[f"signal_{d}"] = ("float32", (nodes, 4))
            args.append(torch.rand(n[d], 4, generator=g))
        ins[f"neighbors_{d}"] = ("int64", (nodes, KERNEL))
        args.append(_table(n[d], g))
        if d < depth:
            ins[f"split_{d}"] = ("int64", (f"splits_{d}",))
            args.append(torch.arange(0, n[d], 4))
    outs = {"latent": ("float32", ("batch", latent))}
    if guided:
        outs.update({f"skip_{d}": ("float32", ("64*batch" if d == full else f"8*splits_{d - 1}",
                                               wrapper.encoder.channels[d])) for d in wrapper.depths})
    return _graph("octree_encoder", wrapper, tuple(args), ins, outs)


def image_encoder_graph(encoder: nn.Module, size: int, latent: int) -> Graph:
    """The image encoder (BN folded): (B, 3, size, size) normalised images -> latent codes."""
    x = torch.rand(2, 3, size, size, generator=torch.Generator().manual_seed(0))
    return _graph("image_encoder", fold_batchnorm(encoder), (x,), {"image": ("float32", ("batch", 3, size, size))},
                  {"latent": ("float32", ("batch", latent))})


def foreground_graph(net: nn.Module, size: int, channels: int = 3, name: str = "foreground") -> Graph:
    """A foreground network (BN folded): (B, channels, size, size) inputs -> object logits; the
    refinement network (``channels`` 4, ``name`` foreground_refine) takes the crop and its first mask."""
    x = torch.rand(2, channels, size, size, generator=torch.Generator().manual_seed(0))
    return _graph(name, fold_batchnorm(net), (x,), {"image": ("float32", ("batch", channels, size, size))},
                  {"logits": ("float32", ("batch", 1, size, size))})


class _Probabilities(nn.Module):
    """A classifier head followed by the softmax (the service reports probabilities)."""

    def __init__(self, head: nn.Module):
        super().__init__()
        self.head = head

    def forward(self, latent):
        return torch.softmax(self.head(latent), 1)


def classifier_head_graph(head: nn.Module, latent: int) -> Graph:
    """The classifier head (dropout is the identity at inference): latent codes -> probabilities."""
    x = torch.rand(2, latent, generator=torch.Generator().manual_seed(0))
    classes = _out_features(head)
    return _graph("classifier_head", _Probabilities(head.eval()), (x,), {"latent": ("float32", ("batch", latent))},
                  {"probabilities": ("float32", ("batch", classes))})


def _out_features(head: nn.Module) -> int:
    return [m for m in head.modules() if isinstance(m, nn.Linear)][-1].out_features
