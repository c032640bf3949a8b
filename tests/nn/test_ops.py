"""Octree ops against dense torch references, brute force on adaptive octrees, gradcheck, tracing."""

import math
import warnings

import numpy as np
import pytest
import torch
import torch.nn.functional as F
from torch import nn

from model.nn import (
    ConvBnRelu,
    DeconvBnRelu,
    LevelTensors,
    OctreeBatchNorm,
    OctreeConv,
    OctreeDeconv,
    OctreeTensors,
    octree_conv,
    octree_deconv,
    octree_max_pool,
    octree_upsample,
)
from model.octree import EMPTY, SPLIT, build_octree, keys
from model.octree.batch import merge_octrees

DENSE_DEPTH = 3
OFFSETS = [(dx, dy, dz) for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)]


def unit_normals(rng, n):
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


@pytest.fixture(scope="module")
def cube():
    """Full octree of a filled cube: every octant of depth DENSE_DEPTH exists and is non-empty."""
    rng = np.random.default_rng(0)
    m = 4 << DENSE_DEPTH                      # grid spacing well below the octant size
    axis = (np.arange(m) + 0.5) / m
    pts = np.stack(np.meshgrid(axis, axis, axis, indexing="ij"), -1).reshape(-1, 3)
    octree = build_octree((pts, unit_normals(rng, len(pts))), DENSE_DEPTH, adaptive=False)
    assert [len(lv) for lv in octree.levels] == [8 ** d for d in range(DENSE_DEPTH + 1)]
    assert all(lv.nonempty.all() for lv in octree.levels)
    return octree, OctreeTensors.from_octree(octree)


def sphere_points(n, seed, center=(0.0, 0.0, 0.0), radius=1.0):
    rng = np.random.default_rng(seed)
    nrm = unit_normals(rng, n)
    return np.asarray(center) + radius * nrm, nrm


@pytest.fixture(scope="module")
def sparse():
    """Adaptive octrees of a sphere and of a box's surface, merged into a batch of two."""
    sphere = build_octree(sphere_points(3000, 1), 5)
    rng = np.random.default_rng(2)
    face = rng.integers(0, 6, 4000)
    pts = rng.uniform(-1, 1, size=(4000, 3)) * np.array([1.0, 0.6, 0.4])
    nrm = np.zeros_like(pts)
    axis, sign = face // 2, np.where(face % 2, 1.0, -1.0)
    pts[np.arange(4000), axis] = sign * np.array([1.0, 0.6, 0.4])[axis]
    nrm[np.arange(4000), axis] = sign
    box = build_octree((pts, nrm), 5)
    octree = merge_octrees([sphere, box])
    return octree, OctreeTensors.from_octree(octree)


def to_dense(x, coords, res):
    """(N, C) features at integer coords -> (1, C, res, res, res)."""
    dense = x.new_zeros(x.shape[1], res, res, res)
    dense[:, coords[:, 0], coords[:, 1], coords[:, 2]] = x.t()
    return dense.unsqueeze(0)


def from_dense(dense, coords):
    return dense[0][:, coords[:, 0], coords[:, 1], coords[:, 2]].t()


def level_coords(octree, depth):
    return torch.from_numpy(keys.decode(octree.levels[depth].key)[0])


def conv3d_weight(w):
    """Ours (27, Cin, Cout), column (dx+1)*9+(dy+1)*3+(dz+1) -> conv3d's (Cout, Cin, 3, 3, 3)."""
    return w.reshape(3, 3, 3, w.shape[1], w.shape[2]).permute(4, 3, 0, 1, 2)


def deconv3d_weight(w):
    """Ours (8, Cin, Cout), slot 4x+2y+z -> conv_transpose3d's (Cin, Cout, 2, 2, 2)."""
    return w.reshape(2, 2, 2, w.shape[1], w.shape[2]).permute(3, 4, 0, 1, 2)


# -- dense equivalence ------------------------------------------------------------------------

@pytest.mark.parametrize("dtype,tol", [(torch.float32, 1e-5), (torch.float64, 1e-12)])
def test_conv_equals_dense_conv3d_with_gradients(cube, dtype, tol):
    octree, t = cube
    torch.manual_seed(0)
    lv, coords, res = t.levels[DENSE_DEPTH], level_coords(octree, DENSE_DEPTH), 1 << DENSE_DEPTH
    x = torch.randn(len(lv), 5, dtype=dtype, requires_grad=True)
    w = torch.randn(27, 5, 7, dtype=dtype, requires_grad=True)
    b = torch.randn(7, dtype=dtype, requires_grad=True)
    xd = to_dense(x.detach(), coords, res).requires_grad_()
    wd = conv3d_weight(w.detach()).contiguous().requires_grad_()
    grad = torch.randn(len(lv), 7, dtype=dtype)

    ours = octree_conv(x, lv.neighbors, w, b)
    ref = from_dense(F.conv3d(xd, wd, b.detach(), padding=1), coords)
    assert torch.allclose(ours, ref, atol=tol, rtol=tol)
    ours.backward(grad)
    ref.backward(grad)
    assert torch.allclose(x.grad, from_dense(xd.grad, coords), atol=tol * 10, rtol=tol)
    assert torch.allclose(conv3d_weight(w.grad), wd.grad, atol=tol * 100, rtol=tol)
    assert torch.allclose(b.grad, grad.sum(0), atol=tol * 10, rtol=tol)


def test_conv_accepts_flat_weight_and_rejects_wrong_shapes(cube):
    _, t = cube
    lv = t.levels[2]
    x, w = torch.randn(len(lv), 4), torch.randn(27, 4, 6)
    assert torch.equal(octree_conv(x, lv.neighbors, w), octree_conv(x, lv.neighbors, w.reshape(108, 6)))
    with pytest.raises(ValueError):
        octree_conv(x, lv.neighbors, torch.randn(27, 2, 12))
    with pytest.raises(ValueError):
        octree_conv(x, lv.neighbors[:, :9], w)


def test_max_pool_equals_dense_max_pool3d_with_gradients(cube):
    octree, t = cube
    torch.manual_seed(0)
    d = DENSE_DEPTH
    fine, coarse = level_coords(octree, d), level_coords(octree, d - 1)
    x = torch.randn(8 ** d, 6, dtype=torch.float64, requires_grad=True)   # distinct: no ties
    xd = to_dense(x.detach(), fine, 1 << d).requires_grad_()
    ours = octree_max_pool(x, t.levels[d - 1].split, len(t.levels[d - 1]))
    ref = from_dense(F.max_pool3d(xd, 2, 2), coarse)
    assert torch.equal(ours, ref)
    grad = torch.randn_like(ours)
    ours.backward(grad)
    ref.backward(grad)
    assert torch.equal(x.grad, from_dense(xd.grad, fine))


def test_deconv_equals_dense_conv_transpose3d_with_gradients(cube):
    octree, t = cube
    torch.manual_seed(0)
    d = DENSE_DEPTH - 1
    coarse, fine = level_coords(octree, d), level_coords(octree, d + 1)
    x = torch.randn(8 ** d, 5, dtype=torch.float64, requires_grad=True)
    w = torch.randn(8, 5, 3, dtype=torch.float64, requires_grad=True)
    xd = to_dense(x.detach(), coarse, 1 << d).requires_grad_()
    wd = deconv3d_weight(w.detach()).contiguous().requires_grad_()
    ours = octree_deconv(x, t.levels[d].split, w)
    ref = from_dense(F.conv_transpose3d(xd, wd, stride=2), fine)
    assert torch.allclose(ours, ref, atol=1e-12)
    grad = torch.randn_like(ours)
    ours.backward(grad)
    ref.backward(grad)
    assert torch.allclose(x.grad, from_dense(xd.grad, coarse), atol=1e-12)
    assert torch.allclose(deconv3d_weight(w.grad), wd.grad, atol=1e-11)


# -- sparse (adaptive, batched) octrees -------------------------------------------------------

def brute_force_conv(level, x, w, rows):
    """out[i] = sum over the 27 offsets of x[node at coords + offset, same shape] @ w[offset]."""
    xyz, batch = keys.decode(level.key)
    where = {(int(b), *map(int, c)): i for i, (c, b) in enumerate(zip(xyz, batch))}
    out = torch.zeros(len(rows), w.shape[2], dtype=x.dtype)
    for r, i in enumerate(rows):
        for k, off in enumerate(OFFSETS):
            j = where.get((int(batch[i]), *(int(c) for c in xyz[i] + np.array(off))))
            if j is not None:
                out[r] += x[j] @ w[k]
    return out


def test_conv_on_adaptive_batched_octree_equals_brute_force(sparse):
    octree, t = sparse
    torch.manual_seed(0)
    d = 4
    lv, nb = octree.levels[d], t.levels[d].neighbors
    assert (nb < 0).any() and len(np.unique(lv.batch)) == 2
    x = torch.randn(len(lv), 3, dtype=torch.float64)
    w = torch.randn(27, 3, 4, dtype=torch.float64)
    missing = (nb < 0).sum(1).numpy()
    rows = np.unique(np.r_[np.flatnonzero(missing == missing.max())[:10],
                           np.flatnonzero(lv.label == EMPTY)[:10],
                           np.random.default_rng(0).choice(len(lv), 20, replace=False),
                           np.flatnonzero(np.diff(lv.batch))[:1] + [0, 1]])
    ours = octree_conv(x, nb, w)
    assert torch.allclose(ours[rows], brute_force_conv(lv, x, w, rows), atol=1e-12)
    # Missing neighbours read zeros: a node whose neighbours all vanish sees only itself.
    alone = torch.full_like(nb, -1)
    alone[:, 13] = torch.arange(len(lv))
    assert torch.allclose(octree_conv(x, alone, w), x @ w[13])


def _conv_with_gradients(sparse):
    """A convolution over depth 5 of the sparse octree, 4 -> 5 float64 channels: a function of
    octree_conv's keywords to (output, input gradient, weight gradient), and the table's rows."""
    _, t = sparse
    torch.manual_seed(0)
    nb = t.levels[5].neighbors
    x = torch.randn(len(nb), 4, dtype=torch.float64, requires_grad=True)
    w = torch.randn(27, 4, 5, dtype=torch.float64, requires_grad=True)
    grad = torch.randn(len(nb), 5, dtype=torch.float64)

    def run(**kw):
        out = octree_conv(x, nb, w, **kw)
        return (out, *torch.autograd.grad(out, (x, w), grad))
    return run, len(nb)


def test_chunked_conv_equals_one_gather_with_gradients(sparse):
    run, n = _conv_with_gradients(sparse)
    results = [run(chunk_rows=rows) for rows in (n, 37, 1)]
    for got in results[1:]:
        for a, b in zip(results[0], got):
            assert torch.allclose(a, b, atol=1e-12)


def test_default_chunk_follows_the_device(sparse, monkeypatch):
    from model.nn import ops

    assert ops.chunk_bytes(torch.device("cpu")) == ops.CPU_CHUNK_BYTES < ops.CHUNK_BYTES
    assert ops.chunk_bytes(torch.device("cuda")) == ops.CHUNK_BYTES
    run, n = _conv_with_gradients(sparse)
    expected = run(chunk_rows=n)
    chunks = []
    gather_mm = ops._gather_mm
    monkeypatch.setattr(ops, "_gather_mm", lambda *a: chunks.append(a[3]) or gather_mm(*a))
    monkeypatch.setattr(ops, "CPU_CHUNK_BYTES", 37 * 27 * 4 * 8)     # 37 rows of 4 float64 channels
    got = run()
    assert chunks[0] == 37 and n > 37
    for a, b in zip(expected, got):
        assert torch.allclose(a, b, atol=1e-12)


def test_chunks_are_balanced():
    from model.nn.ops import _chunks

    for n in (1, 7, 8, 100, 2427, 2428, 4860, 10_001):
        for limit in (1, 8, 37, 2427, 10_000):
            chunks = _chunks(n, limit)
            sizes = [c.stop - c.start for c in chunks]
            assert chunks[0].start == 0 and chunks[-1].stop == n
            assert all(a.stop == b.start for a, b in zip(chunks, chunks[1:]))
            assert max(sizes) <= limit and len(sizes) == -(-n // limit)   # as few chunks as the limit allows
            assert max(sizes) - min(sizes) <= 1                         # no short last chunk


def test_max_pool_zeroes_nodes_without_children(sparse):
    octree, t = sparse
    torch.manual_seed(0)
    d = 4
    up, split = octree.levels[d - 1], t.levels[d - 1].split
    x = torch.randn(len(octree.levels[d]), 3) - 1.0             # mostly negative: max stays negative
    out = octree_max_pool(x, split, len(up))
    want = torch.zeros(len(up), 3)
    for i in np.flatnonzero(up.child >= 0):
        k = int(up.child[i])
        want[i] = x[8 * k:8 * k + 8].max(0).values
    assert torch.equal(out, want)
    assert (out[torch.from_numpy(up.label != SPLIT)] == 0).all() and (out[split] < 0).any()


def test_deconv_and_upsample_rows_follow_children_order(sparse):
    octree, t = sparse
    torch.manual_seed(0)
    d = 3
    up, down, split = octree.levels[d], octree.levels[d + 1], t.levels[d].split
    morton = np.uint64((1 << keys.BATCH_SHIFT) - 1)
    parent_key = up.key[split.numpy()]
    child_key = (((parent_key & morton) << np.uint64(3)) | (parent_key & ~morton))[:, None] \
        | np.arange(8, dtype=np.uint64)
    assert np.array_equal(child_key.ravel(), down.key)          # row 8k+s is child slot s of split[k]
    x, w = torch.randn(len(up), 3), torch.randn(8, 3, 2)
    out = octree_deconv(x, split, w).reshape(-1, 8, 2)
    want = torch.einsum("kc,scd->ksd", x[split], w)
    assert out.shape == (len(split), 8, 2) and torch.allclose(out, want, atol=1e-6)
    assert torch.equal(octree_upsample(x, split).reshape(-1, 8, 3), x[split].unsqueeze(1).expand(-1, 8, -1))


# -- gradcheck ----------------------------------------------------------------------------------

def tiny_neighbors(t, n=24):
    """The first n octants of depth 3 with every neighbour beyond them dropped (-1)."""
    nb = t.levels[3].neighbors[:n].clone()
    nb[nb >= n] = -1
    return nb


def test_gradcheck_conv(sparse):
    _, t = sparse
    torch.manual_seed(0)
    nb = tiny_neighbors(t)
    x = torch.randn(len(nb), 2, dtype=torch.float64, requires_grad=True)
    w = torch.randn(27, 2, 3, dtype=torch.float64, requires_grad=True)
    b = torch.randn(3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x, w, b: octree_conv(x, nb, w, b), (x, w, b))
    assert torch.autograd.gradcheck(lambda x, w: octree_conv(x, nb, w, chunk_rows=5), (x, w))


def test_gradcheck_max_pool(sparse):
    _, t = sparse
    split, n = t.levels[3].split[:4], len(t.levels[3])
    x = (torch.randperm(32 * 2, dtype=torch.float64) / 7).reshape(32, 2).requires_grad_()   # distinct
    assert torch.autograd.gradcheck(lambda x: octree_max_pool(x, split, n), (x,))


def test_gradcheck_deconv(sparse):
    _, t = sparse
    torch.manual_seed(0)
    split = t.levels[3].split[:3]
    x = torch.randn(10 + int(split.max()), 2, dtype=torch.float64, requires_grad=True)
    w = torch.randn(8, 2, 3, dtype=torch.float64, requires_grad=True)
    b = torch.randn(3, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x, w, b: octree_deconv(x, split, w, b), (x, w, b))


# -- modules, init, batch norm, tensors, tracing ---------------------------------------------------

def test_init_bounds_match_torch_conv_layers():
    torch.manual_seed(0)
    for ours, ref in ((OctreeConv(16, 24, bias=True), nn.Conv3d(16, 24, 3)),
                      (OctreeDeconv(16, 24, bias=True), nn.ConvTranspose3d(16, 24, 2, 2))):
        fan_in, _ = nn.init._calculate_fan_in_and_fan_out(ref.weight)
        bound = 1 / math.sqrt(fan_in)
        for p in (ours.weight, ours.bias):
            assert p.abs().max() <= bound and p.abs().max() > 0.9 * bound
    assert OctreeConv(3, 5).bias is None and OctreeConv(3, 5).weight.shape == (27, 3, 5)
    assert OctreeDeconv(3, 5).weight.shape == (8, 3, 5)


def test_batch_norm_normalises_over_all_octants():
    torch.manual_seed(0)
    bn = OctreeBatchNorm(4)
    assert isinstance(bn, nn.BatchNorm1d)
    x = torch.randn(500, 4) * torch.tensor([1.0, 2.0, 3.0, 4.0]) + 5.0
    y = bn(x)
    want = (x - x.mean(0)) / torch.sqrt(x.var(0, unbiased=False) + bn.eps)
    assert torch.allclose(y, want, atol=1e-5)
    assert torch.allclose(bn.running_mean, 0.1 * x.mean(0), atol=1e-5)


def test_octree_tensors_mirror_the_octree(sparse):
    octree, t = sparse
    assert t.depth == octree.depth and t.batch_size == 2 and len(t.levels) == octree.depth + 1
    for lv, tl in zip(octree.levels, t.levels):
        assert isinstance(tl, LevelTensors) and len(tl) == len(lv)
        assert tl.neighbors.dtype == tl.split.dtype == tl.parent.dtype == tl.label.dtype == torch.int64
        assert tl.plane.dtype == torch.float32 and tl.nonempty.dtype == torch.bool
        assert np.array_equal(tl.neighbors.numpy(), lv.neighbors)
        assert np.array_equal(tl.split.numpy(), np.flatnonzero(lv.label == SPLIT))
        assert np.array_equal(tl.nonempty.numpy(), lv.label != EMPTY)
        assert np.array_equal(tl.plane.numpy(), lv.plane) and np.array_equal(tl.parent.numpy(), lv.parent)
    moved = t.to("meta")                      # every table moves, and to a new tensor
    for name in LevelTensors.__dataclass_fields__:
        a, b = getattr(moved.levels[3], name), getattr(t.levels[3], name)
        assert a.device.type == "meta" and b.device.type == "cpu" and a.shape == b.shape and a.dtype == b.dtype
    with pytest.raises(ValueError):
        OctreeTensors.from_octree(build_octree(sphere_points(200, 3), 4, neighbors=False))


class TinyNet(nn.Module):
    """Conv at depth d, pool to d-1 fused by max, deconv back to d: every op in one graph."""

    def __init__(self):
        super().__init__()
        self.fine = ConvBnRelu(4, 8)
        self.coarse = ConvBnRelu(4, 8)
        self.up = DeconvBnRelu(8, 6)

    def forward(self, plane_d, nb_d, plane_c, nb_c, split_c):
        x = self.fine(plane_d, nb_d)
        x = torch.maximum(octree_max_pool(x, split_c, nb_c.shape[0]), self.coarse(plane_c, nb_c))
        return self.up(x, split_c)


def tiny_inputs(t, d):
    return (t.levels[d].plane, t.levels[d].neighbors, t.levels[d - 1].plane,
            t.levels[d - 1].neighbors, t.levels[d - 1].split)


@pytest.mark.filterwarnings("ignore:`torch.jit.trace:DeprecationWarning")
def test_jit_trace_generalises_to_other_octrees(sparse, cube):
    _, t = sparse
    torch.manual_seed(0)
    net = TinyNet()
    net.train()
    for _ in range(3):                                  # non-trivial running statistics
        net(*tiny_inputs(t, 5))
    net.eval()
    with warnings.catch_warnings():
        warnings.simplefilter("error", torch.jit.TracerWarning)
        traced = torch.jit.trace(net, tiny_inputs(t, 5))
    for inputs in (tiny_inputs(t, 4), tiny_inputs(cube[1], DENSE_DEPTH), tiny_inputs(t, 5)):
        with torch.no_grad():
            want = net(*inputs)
        got = traced(*inputs)
        assert got.shape == want.shape and torch.allclose(got, want, atol=1e-5)
    graph = str(traced.inlined_graph)
    assert "aten::index_select" in graph and "aten::index_put" in graph


def test_torch_export_with_dynamic_sizes(sparse, cube):
    _, t = sparse
    torch.manual_seed(0)
    net = TinyNet().eval()
    m, k = torch.export.Dim("m"), torch.export.Dim("k")
    n = 8 * k                                             # depth d holds the 8 children of k splits
    exported = torch.export.export(net, tiny_inputs(t, 5),
                                   dynamic_shapes=({0: n}, {0: n}, {0: m}, {0: m}, {0: k}))
    for inputs in (tiny_inputs(t, 4), tiny_inputs(cube[1], DENSE_DEPTH)):
        with torch.no_grad():
            assert torch.allclose(exported.module()(*inputs), net(*inputs), atol=1e-5)


def test_the_hand_written_convolution_backward_equals_autograd(sparse, monkeypatch):
    """Gradcheck in float64, and float32 gradients equal to autograd's scatter-add formulation on
    a real octree's tables, with and without chunking (the input gradient relies on the
    neighbour table's symmetry)."""
    import model.nn.ops as ops
    from model.nn.ops import KERNEL, _OctreeConvFunction

    monkeypatch.setattr(ops, "CUSTOM_BACKWARD_ROWS", 0)      # every size through the hand-written one
    used = []
    original = _OctreeConvFunction.backward
    monkeypatch.setattr(_OctreeConvFunction, "backward", staticmethod(lambda ctx, g: used.append(1) or original(ctx, g)))

    _, t = sparse
    small = t.levels[2].neighbors                   # 128 octants: the numerical Jacobian is O(N^2)
    x = torch.randn(len(small), 2, dtype=torch.float64, requires_grad=True)
    w = torch.randn(KERNEL * 2, 2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda x, w: _OctreeConvFunction.apply(x, small, w, 13), (x, w), eps=1e-6,
                                    atol=1e-6)
    for d in (3, 4, 5):
        nb = t.levels[d].neighbors
        n = len(nb)
        for chunk in (None, 17):
            x32 = torch.randn(n, 8, requires_grad=True)
            w32 = torch.randn(KERNEL, 8, 16, requires_grad=True)
            g = torch.randn(n, 16)
            octree_conv(x32, nb, w32, chunk_rows=chunk).backward(g)
            got = x32.grad.clone(), w32.grad.clone()
            x32.grad = w32.grad = None
            padded = torch.cat([x32.new_zeros(1, 8), x32])            # autograd's formulation
            padded.index_select(0, (nb + 1).reshape(-1)).view(n, -1).mm(w32.reshape(-1, 16)).backward(g)
            scale = float(x32.grad.abs().max())
            assert torch.allclose(got[0], x32.grad, atol=1e-5 * scale) and torch.allclose(got[1], w32.grad, rtol=1e-4,
                                                                                          atol=1e-4)
    assert len(used) >= 6                                      # octree_conv took the hand-written backward
