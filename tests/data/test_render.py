"""Renderer: silhouette geometry, centring, transparency, compositing, speed-relevant API."""

import numpy as np
import trimesh

from model.data.render import composite, metadata_row, rasterize, render, render_views
from model.data.shapes import generate


def test_unit_cube_silhouette_matches_projection():
    cube = trimesh.creation.box()
    size, fov, dist = 137, 25.0, 3.0
    img, cam = render(cube, 0.0, 0.0, dist, size=size, fov_deg=fov)
    alpha = img[..., 3] > 0
    focal = 0.5 * size / np.tan(np.radians(fov / 2))
    side = 2 * focal * 0.5 / (dist - 0.5)  # front face at z = 0.5 seen head-on
    cols = np.nonzero(alpha.any(axis=0))[0]
    rows = np.nonzero(alpha.any(axis=1))[0]
    assert abs((cols[-1] - cols[0] + 1) - side) <= 1.0
    assert abs((rows[-1] - rows[0] + 1) - side) <= 1.0
    assert abs(alpha.sum() - side**2) < 2 * side
    assert cam == {"azimuth": 0.0, "elevation": 0.0, "in_plane_rotation": 0.0, "distance": 3.0, "fov": 25.0}


def test_cube_corner_view_shows_three_faces_with_different_shades():
    img, _ = render(trimesh.creation.box(), 45.0, 35.26, 3.0, size=64)
    shades = np.unique(img[..., 0][img[..., 3] == 255])
    assert len(shades) == 3


def test_render_centred_and_transparent():
    mesh = generate("chair", 0)
    imgs, cams = render_views(mesh, n_views=6, rng=np.random.default_rng(0))
    assert imgs.shape == (6, 137, 137, 4) and imgs.dtype == np.uint8
    for img, cam in zip(imgs, cams):
        a = img[..., 3].astype(np.float64)
        assert a.sum() > 500
        for corner in (a[0, 0], a[0, -1], a[-1, 0], a[-1, -1]):
            assert corner == 0
        ys, xs = np.mgrid[:137, :137]
        cy, cx = (ys * a).sum() / a.sum(), (xs * a).sum() / a.sum()
        assert abs(cx - 68) < 14 and abs(cy - 68) < 14
        assert 0 <= cam["azimuth"] < 360 and 25 <= cam["elevation"] <= 30
        assert cam["in_plane_rotation"] == 0.0 and cam["fov"] == 25.0
        row = metadata_row(cam)
        assert len(row) == 5 and 0.65 <= row[3] <= 0.85


def test_sphere_render_is_centred_disc():
    img, _ = render(trimesh.creation.icosphere(3, radius=0.5), 123.0, 27.0, 3.0, size=101)
    a = img[..., 3] > 0
    ys, xs = np.nonzero(a)
    assert abs(xs.mean() - 50) < 0.5 and abs(ys.mean() - 50) < 0.5


def test_depth_test_keeps_nearest_triangle():
    xy = np.array([[0, 0], [10, 0], [0, 10], [0, 0], [10, 0], [0, 10]], dtype=float)
    depth = np.array([2, 2, 2, 1, 1, 1], dtype=float)
    zbuf, fid = rasterize(xy, depth, np.array([[0, 1, 2], [3, 4, 5]]), 10, 10)
    covered = fid >= 0
    assert (fid[covered] == 1).all() and np.allclose(zbuf[covered], 1.0)
    assert covered.sum() == 55  # pixel centres (j+.5, i+.5) with i + j <= 9


def test_composite():
    rgba = np.zeros((8, 8, 4), dtype=np.uint8)
    rgba[2:6, 2:6] = [200, 10, 10, 255]
    out = composite(rgba, (0, 0, 255))
    assert out.shape == (8, 8, 3)
    assert (out[0, 0] == [0, 0, 255]).all() and (out[3, 3] == [200, 10, 10]).all()
    rng = np.random.default_rng(0)
    backgrounds = [composite(rgba, None, rng) for _ in range(6)]
    assert all((b[3, 3] == [200, 10, 10]).all() for b in backgrounds)
    assert len({b[0, 0].tobytes() for b in backgrounds}) > 1
