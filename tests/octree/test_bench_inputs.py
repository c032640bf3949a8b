"""The build benchmark's inputs to ocnn: snapped so that float32 key arithmetic is exact."""

import numpy as np

from bench.octree_build import SNAP, ocnn_inputs, snapped_cube


def _float32_voxels(x32: np.ndarray, depth: int) -> np.ndarray:
    """ocnn's key arithmetic: floor((x + 1) * 2^(depth-1)) computed in float32."""
    return np.floor((x32 + np.float32(1.0)) * np.float32(2 ** (depth - 1))).astype(np.int64)


def test_snapped_inputs_put_every_point_in_the_same_octant_in_float32_and_float64():
    rng = np.random.default_rng(0)
    depth = 8
    # points within 1e-9 of octant boundaries, where float32 rounding decides otherwise
    edges = rng.integers(1, 2 ** depth, size=(20000, 3)) / 2 ** depth
    pts = edges + rng.uniform(-1e-9, 1e-9, edges.shape)
    pts = np.vstack([pts, [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0]]])      # the bounding box ends
    normals = np.tile([0.0, 0.0, 1.0], (len(pts), 1))
    cube = snapped_cube(pts)
    assert np.abs(cube - np.round(cube / SNAP) * SNAP).max() == 0
    xyz, _ = ocnn_inputs(pts, normals)
    x32 = xyz.numpy()
    assert np.array_equal(x32.astype(np.float64), (cube - 0.5) * 2.0)       # exact in float32
    ours = np.clip(np.floor(cube * 2 ** depth).astype(np.int64), 0, 2 ** depth - 1)
    theirs = np.clip(_float32_voxels(x32, depth), 0, 2 ** depth - 1)
    assert np.array_equal(ours, theirs)
    # without snapping, float32 arithmetic moves some of these points across a boundary
    from model.octree.pointcloud import normalization_of
    unsnapped = normalization_of(pts).to_cube(pts)
    u32 = ((unsnapped - 0.5) * 2.0).astype(np.float32)
    exact = np.clip(np.floor(unsnapped * 2 ** depth).astype(np.int64), 0, 2 ** depth - 1)
    assert (np.clip(_float32_voxels(u32, depth), 0, 2 ** depth - 1) != exact).any()
