"""Octree CNN operations on per-depth feature tables (N, C), for the networks of paper section 4.

Data moves only through index_select, reshape/view/expand, cat and index_put, arithmetic is
matmul and element-wise, and a captured graph (jit trace, torch.export, ONNX) has no loop over
nodes and no branch on data.  Autograd derives every backward pass except the convolution's
when training eagerly, which is hand-written as a gather + GEMM (:class:`_OctreeConvFunction`).
Features of a depth are rows in node order; neighbour and split tables come from
:class:`model.nn.tensors.LevelTensors`.
"""

from __future__ import annotations

import math

import torch
from torch import nn

KERNEL = 27
"""Neighbours of a 3x3x3 kernel: column (dx+1)*9 + (dy+1)*3 + (dz+1), 13 is the node itself."""
CHILDREN = 8
"""Children of a split node: slot 4x + 2y + z."""
CHUNK_BYTES = 16 << 20
"""Eager convolution on an accelerator gathers at most this many bytes of neighbour rows per GEMM
(see octree_conv)."""
CPU_CHUNK_BYTES = 2 << 20
"""The same on the CPU: a chunk small enough to stay in the cache from its gather to its GEMM.
Against 16 MiB, an autoencoder training step (batch 8) takes 0.76 of the time at depth 7 and 0.86
at depth 6 with 1 thread, 0.78 and 0.91 with 2; 1 and 4 MiB were within 8% of it either way, 0.5
MiB 3-20% slower (``python -m bench.conv_chunks``, 2 AMD EPYC cores)."""
CUSTOM_BACKWARD_ROWS = 4096
"""Convolutions over more octants than this use the hand-written backward when training; below it
autograd's is as fast (measured: bench.train_step), without the extra Python."""


def chunk_bytes(device: torch.device) -> int:
    """Bytes of gathered neighbour rows per GEMM of an eager convolution on ``device``."""
    return CPU_CHUNK_BYTES if device.type == "cpu" else CHUNK_BYTES


def _chunk_rows(t: torch.Tensor, channels: int) -> int:
    """Rows per chunk when neighbour rows of ``channels`` features of ``t``'s dtype are gathered on
    ``t``'s device: :func:`chunk_bytes` of them, at least one row."""
    return max(1, chunk_bytes(t.device) // (KERNEL * channels * t.element_size()))


def graph_capture() -> bool:
    """True while a graph is being recorded (jit trace, torch.compile / torch.export, ONNX export).

    Ops then take their single, size-independent formulation so the graph works for any N.
    """
    return torch.jit.is_tracing() or torch.compiler.is_compiling() or torch.onnx.is_in_onnx_export()


def _check(ok: bool, message: str) -> None:
    if not ok:
        raise ValueError(message)


def octree_conv(x: torch.Tensor, neighbors: torch.Tensor, weight: torch.Tensor,
                bias: torch.Tensor | None = None, *, chunk_rows: int | None = None) -> torch.Tensor:
    """3x3x3 convolution, stride 1, over the N octants of one depth: (N, Cin) -> (N, Cout).

    ``neighbors`` (N, 27) int64 with -1 for a missing neighbour, which reads zeros; ``weight`` is
    (27, Cin, Cout) or (27*Cin, Cout) in the neighbour column order.  The neighbour rows are
    gathered into an (n, 27*Cin) matrix and multiplied by the weight in one GEMM.

    While a graph is captured all N rows form one gather + GEMM.  Eagerly the rows are split into
    chunks of ``chunk_rows`` (default: :func:`chunk_bytes` of gathered features): one gather of a
    large N allocates 27*N*Cin floats afresh, and on CPU page-faulting that memory cost more than
    the GEMM itself (bench/conv.py); chunks stay small enough for the allocator to reuse, and on the
    CPU for the cache to hold a chunk from its gather to its GEMM (:data:`CPU_CHUNK_BYTES`).  When
    training eagerly the backward is :class:`_OctreeConvFunction`'s (gather + GEMM, no scatter).
    """
    cin = x.shape[1]
    capture = graph_capture()
    if not capture:
        _check(neighbors.dim() == 2 and neighbors.shape[1] == KERNEL
               and neighbors.shape[0] == x.shape[0], "neighbors must be (N, 27) for x of N rows")
        _check(tuple(weight.shape[:2]) == (KERNEL, cin) if weight.dim() == 3
               else weight.dim() == 2 and weight.shape[0] == KERNEL * cin,
               f"weight must be (27, {cin}, Cout) or ({KERNEL * cin}, Cout), got {tuple(weight.shape)}")
        if chunk_rows is None:
            chunk_rows = _chunk_rows(x, cin)
    w = weight.reshape(KERNEL * cin, weight.shape[-1])
    if capture:
        # Row 0 is a zero row, so neighbour j is row j+1 and a missing one (-1) reads row 0.
        padded = torch.cat([x.new_zeros(1, cin), x])
        out = padded.index_select(0, (neighbors + 1).reshape(-1)).view(neighbors.shape[0], KERNEL * cin).mm(w)
    elif torch.is_grad_enabled() and (x.requires_grad or w.requires_grad) and x.shape[0] > CUSTOM_BACKWARD_ROWS:
        out = _OctreeConvFunction.apply(x, neighbors, w, chunk_rows)
    else:
        out = _gather_mm(x, neighbors, w, chunk_rows)
    return out if bias is None else out + bias


def _chunks(n: int, chunk_rows: int) -> list[slice]:
    """``n`` rows cut into as few chunks of at most ``chunk_rows`` as there can be, of sizes that
    differ by at most one: no short last chunk.  A GEMM of fewer than 8 rows takes another kernel,
    whose sums round differently, so a short chunk made a row's result depend on where its batch
    put it (a shape's code on the shapes batched with it)."""
    parts = -(-n // chunk_rows)
    return [slice(i * n // parts, (i + 1) * n // parts) for i in range(parts)]


def _gather_mm(x: torch.Tensor, neighbors: torch.Tensor, w: torch.Tensor, chunk_rows: int) -> torch.Tensor:
    """Rows of ``neighbors`` gathered from ``x`` (a zero row for -1) times ``w``, chunk by chunk
    (:func:`_chunks`)."""
    cin = x.shape[1]
    padded = torch.cat([x.new_zeros(1, cin), x])
    index = (neighbors + 1).contiguous()
    n = index.shape[0]
    if n <= chunk_rows:
        return padded.index_select(0, index.reshape(-1)).view(n, KERNEL * cin).mm(w)
    if (torch.is_grad_enabled() and (x.requires_grad or w.requires_grad)) or torch.is_autocast_enabled(x.device.type):
        # autograd's backward, or autocast (mm's out= variant is not autocast)
        return torch.cat([padded.index_select(0, index[c].reshape(-1)).view(-1, KERNEL * cin).mm(w)
                          for c in _chunks(n, chunk_rows)])
    out = x.new_empty(n, w.shape[1])
    for c in _chunks(n, chunk_rows):
        torch.mm(padded.index_select(0, index[c].reshape(-1)).view(-1, KERNEL * cin), w, out=out[c])
    return out


class _OctreeConvFunction(torch.autograd.Function):
    """The convolution with a hand-written backward, used when training eagerly.

    A neighbour table of one depth is symmetric: if j is n's neighbour at offset o, n is j's at
    offset -o (column 26 - k).  So the input gradient is the same gather + GEMM as the forward,
    with the kernel flipped and transposed, instead of autograd's scatter-add of the gathered
    rows; the weight gradient is the gathered rows' transpose times the output gradient,
    accumulated chunk by chunk.  Graph capture never sees this function.
    """

    @staticmethod
    def forward(ctx, x, neighbors, w, chunk_rows):
        ctx.save_for_backward(x, neighbors, w)
        ctx.chunk_rows = chunk_rows
        return _gather_mm(x, neighbors, w, chunk_rows)

    @staticmethod
    def backward(ctx, grad):
        x, neighbors, w = ctx.saved_tensors
        cin, cout = x.shape[1], w.shape[1]
        # under autocast (mixed precision) x and the gradient may be bfloat16 and w float32: the
        # backward runs in the widest of the three dtypes and returns each gradient in its input's
        dtype = torch.promote_types(torch.promote_types(x.dtype, w.dtype), grad.dtype)
        x_dtype, x, grad = x.dtype, x.to(dtype), grad.to(dtype).contiguous()
        gx = gw = None
        if ctx.needs_input_grad[0]:
            wt = w.view(KERNEL, cin, cout).flip(0).transpose(1, 2).reshape(KERNEL * cout, cin)
            gx = _gather_mm(grad, neighbors, wt, _chunk_rows(grad, cout)).to(x_dtype)
        if ctx.needs_input_grad[2]:
            padded = torch.cat([x.new_zeros(1, cin), x])
            index = (neighbors + 1).contiguous()
            gw = w.new_zeros(KERNEL * cin, cout)
            for c in _chunks(index.shape[0], ctx.chunk_rows):
                cols = padded.index_select(0, index[c].reshape(-1)).view(-1, KERNEL * cin)
                gw.addmm_(cols.t(), grad[c])
        return gx, None, gw, None


def octree_max_pool(x_children: torch.Tensor, split: torch.Tensor, n_parent: int) -> torch.Tensor:
    """Max-pooling (kernel 2, stride 2) to the parent depth: (8K, C) children of the K split nodes
    -> (n_parent, C); rows of nodes without children are 0.

    Children rows 8k..8k+7 are max-reduced (ReduceMax) and written into row ``split[k]`` of a zero
    table (ScatterND).  Features reaching the pool come out of a ReLU, so they are >= 0 and 0 is
    the neutral value for the encoder's element-wise max fusion with the parent depth.  Tied
    maxima share the gradient equally (F.max_pool3d gives it to one of them).
    """
    c = x_children.shape[1]
    if not graph_capture():
        _check(x_children.shape[0] == CHILDREN * split.shape[0],
               f"x_children has {x_children.shape[0]} rows, expected 8 * {split.shape[0]}")
    pooled = x_children.reshape(-1, CHILDREN, c).amax(1)
    return x_children.new_zeros(n_parent, c).index_put((split,), pooled)


def octree_deconv(x: torch.Tensor, split: torch.Tensor, weight: torch.Tensor,
                  bias: torch.Tensor | None = None) -> torch.Tensor:
    """Deconvolution (kernel 2, stride 2) to the children: (N, Cin) -> (8K, Cout).

    ``weight`` (8, Cin, Cout) by child slot; row 8k+s of the output is child slot s of the k-th
    split node ``split[k]``, i.e. node 8k+s of the next depth.  One gather and one GEMM.
    """
    cin, cout = x.shape[1], weight.shape[-1]
    if not graph_capture():
        _check(tuple(weight.shape) == (CHILDREN, cin, cout),
               f"weight must be (8, {cin}, Cout), got {tuple(weight.shape)}")
    w = weight.permute(1, 0, 2).reshape(cin, CHILDREN * cout)
    out = x.index_select(0, split).mm(w).reshape(-1, cout)
    return out if bias is None else out + bias


def octree_upsample(x: torch.Tensor, split: torch.Tensor) -> torch.Tensor:
    """Nearest up-sampling: (N, C) -> (8K, C), each split node's row copied to its 8 children."""
    return x.index_select(0, split.unsqueeze(1).expand(-1, CHILDREN).reshape(-1))


def skip_gather(skip: torch.Tensor, index: torch.Tensor) -> torch.Tensor:
    """Rows of another octree's features at these octants: (M, C) features of M octants and (N,)
    rows into them (:func:`model.octree.keys.lookup`: M where the octant has no match) -> (N, C),
    zeros for the unmatched.  Concat + Gather in ONNX."""
    return torch.cat([skip, skip.new_zeros(1, skip.shape[1])]).index_select(0, index)


def _uniform_(tensor: torch.Tensor, fan_in: int) -> None:
    """U(-1/sqrt(fan_in), 1/sqrt(fan_in)): what nn.Conv3d's kaiming_uniform_(a=sqrt(5)) gives."""
    bound = 1.0 / math.sqrt(fan_in) if fan_in > 0 else 0.0
    nn.init.uniform_(tensor, -bound, bound)


class OctreeConv(nn.Module):
    """3x3x3 octree convolution, stride 1 (:func:`octree_conv`); weight (27, Cin, Cout)."""

    def __init__(self, cin: int, cout: int, bias: bool = False):
        super().__init__()
        self.cin, self.cout = cin, cout
        self.weight = nn.Parameter(torch.empty(KERNEL, cin, cout))
        self.bias = nn.Parameter(torch.empty(cout)) if bias else None
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """As nn.Conv3d(cin, cout, 3): fan_in = 27 * cin for weight and bias."""
        _uniform_(self.weight, KERNEL * self.cin)
        if self.bias is not None:
            _uniform_(self.bias, KERNEL * self.cin)

    def forward(self, x: torch.Tensor, neighbors: torch.Tensor) -> torch.Tensor:
        return octree_conv(x, neighbors, self.weight, self.bias)

    def extra_repr(self) -> str:
        return f"{self.cin}, {self.cout}, bias={self.bias is not None}"


class OctreeDeconv(nn.Module):
    """Octree deconvolution, kernel 2, stride 2, to the children (:func:`octree_deconv`)."""

    def __init__(self, cin: int, cout: int, bias: bool = False):
        super().__init__()
        self.cin, self.cout = cin, cout
        self.weight = nn.Parameter(torch.empty(CHILDREN, cin, cout))
        self.bias = nn.Parameter(torch.empty(cout)) if bias else None
        self.reset_parameters()

    def reset_parameters(self) -> None:
        """As nn.ConvTranspose3d(cin, cout, 2, 2), whose init takes fan_in = 8 * cout."""
        _uniform_(self.weight, CHILDREN * self.cout)
        if self.bias is not None:
            _uniform_(self.bias, CHILDREN * self.cout)

    def forward(self, x: torch.Tensor, split: torch.Tensor) -> torch.Tensor:
        return octree_deconv(x, split, self.weight, self.bias)

    def extra_repr(self) -> str:
        return f"{self.cin}, {self.cout}, bias={self.bias is not None}"


class OctreeBatchNorm(nn.BatchNorm1d):
    """Batch normalisation of (N, C) octree features: statistics over all N octants of a depth."""


class ConvBnRelu(nn.Module):
    """OctreeConv + OctreeBatchNorm + ReLU, the conv(c) block of the paper's appendix."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.conv = OctreeConv(cin, cout)
        self.bn = OctreeBatchNorm(cout)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x: torch.Tensor, neighbors: torch.Tensor) -> torch.Tensor:
        return self.relu(self.bn(self.conv(x, neighbors)))


class DeconvBnRelu(nn.Module):
    """OctreeDeconv + OctreeBatchNorm + ReLU: features of split octants handed to their children."""

    def __init__(self, cin: int, cout: int):
        super().__init__()
        self.deconv = OctreeDeconv(cin, cout)
        self.bn = OctreeBatchNorm(cout)
        self.relu = nn.ReLU(inplace=True)

    def forward(self, x: torch.Tensor, split: torch.Tensor) -> torch.Tensor:
        return self.relu(self.bn(self.deconv(x, split)))
