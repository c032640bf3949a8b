"""NumPy z-buffer triangle rasterizer and 3D-R2N2-style renderer.

Renders a mesh with a perspective camera looking at the origin (+Y up),
two-sided Lambert shading (headlight + key light + ambient) and a
transparent background, as the single-image reconstruction task needs
(paper section 5, "Shape reconstruction from a single image").  The same
rasterizer, with an orthographic projection, is the ray-casting fallback
of the virtual scanner.

Camera convention: azimuth ``a`` and elevation ``e`` (degrees) put the eye at
``distance * (cos e sin a, sin e, cos e cos a)``, so azimuth 0 looks at the
shape's front (+Z) and positive elevation looks down on it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

R2N2_FOV_DEG = 25.0
"""Field of view of the 3D-R2N2 renderings (last column of rendering_metadata.txt)."""
R2N2_MAX_DISTANCE = 4.0
"""Camera distance for a distance ratio of 1 (shapes have longest bbox edge 1)."""

_CHUNK = 2_000_000


def rasterize(
    xy: np.ndarray, depth: np.ndarray, faces: np.ndarray, width: int, height: int
) -> tuple[np.ndarray, np.ndarray]:
    """Z-buffer triangles given in pixel coordinates; smallest depth wins.

    Pixel (row i, column j) samples the point (j + 0.5, i + 0.5); ``depth`` is
    interpolated linearly in screen space.  Returns (zbuf float64 with inf
    where empty, face index int64 with -1 where empty), both (height, width).
    """
    xy = np.asarray(xy, dtype=np.float64)
    depth = np.asarray(depth, dtype=np.float64)
    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    zbuf = np.full(width * height, np.inf)
    fbuf = np.full(width * height, -1, dtype=np.int64)
    tri = _on_screen(xy[faces], depth[faces], width, height) if len(faces) else None
    if tri is not None:
        counts = tri.w * tri.h
        ends = np.cumsum(counts)
        start = 0
        while start < len(tri.idx):
            base = ends[start - 1] if start > 0 else 0
            stop = max(int(np.searchsorted(ends, base + _CHUNK, side="right")), start + 1)
            _fill(tri, start, stop, counts, ends, base, width, zbuf, fbuf)
            start = stop
    return zbuf.reshape(height, width), fbuf.reshape(height, width)


@dataclass
class _Triangles:
    """The triangles that reach the screen (``idx``: their face numbers): their pixel boxes
    (``jmin``, ``imin``, width ``w``, height ``h``) and, as affine functions ``a x + b y + c`` of
    the pixel centre, two barycentric coordinates (``l0``, ``l1``) and the depth (``z``)."""

    idx: np.ndarray
    jmin: np.ndarray
    imin: np.ndarray
    w: np.ndarray
    h: np.ndarray
    l0: tuple[np.ndarray, np.ndarray, np.ndarray]
    l1: tuple[np.ndarray, np.ndarray, np.ndarray]
    z: tuple[np.ndarray, np.ndarray, np.ndarray]


def _on_screen(t: np.ndarray, z: np.ndarray, width: int, height: int) -> _Triangles | None:
    """The triangles ``t`` (F, 3, 2 pixel coordinates; depths ``z`` (F, 3)) that are finite, not
    degenerate and overlap the screen, as :class:`_Triangles` (None when there is none)."""
    x0, x1, x2 = t[:, 0, 0], t[:, 1, 0], t[:, 2, 0]
    y0, y1, y2 = t[:, 0, 1], t[:, 1, 1], t[:, 2, 1]
    d = (y1 - y2) * (x0 - x2) + (x2 - x1) * (y0 - y2)
    with np.errstate(all="ignore"):
        jmin = np.ceil(np.minimum(np.minimum(x0, x1), x2) - 0.5)
        jmax = np.floor(np.maximum(np.maximum(x0, x1), x2) - 0.5)
        imin = np.ceil(np.minimum(np.minimum(y0, y1), y2) - 0.5)
        imax = np.floor(np.maximum(np.maximum(y0, y1), y2) - 0.5)
    ok = (np.isfinite(t).all(axis=(1, 2)) & np.isfinite(z).all(axis=1) & (np.abs(d) > 1e-12)
          & (jmax >= 0) & (imax >= 0) & (jmin <= width - 1) & (imin <= height - 1))
    idx = np.nonzero(ok)[0]
    if len(idx) == 0:
        return None
    jmin = np.clip(jmin[idx], 0, width - 1).astype(np.int64)
    jmax = np.clip(jmax[idx], 0, width - 1).astype(np.int64)
    imin = np.clip(imin[idx], 0, height - 1).astype(np.int64)
    imax = np.clip(imax[idx], 0, height - 1).astype(np.int64)
    x0, x1, x2, y0, y1, y2, d = (a[idx] for a in (x0, x1, x2, y0, y1, y2, d))
    a0, b0 = (y1 - y2) / d, (x2 - x1) / d
    c0 = -(a0 * x2 + b0 * y2)
    a1, b1 = (y2 - y0) / d, (x0 - x2) / d
    c1 = -(a1 * x2 + b1 * y2)
    zz = z[idx]
    za = a0 * (zz[:, 0] - zz[:, 2]) + a1 * (zz[:, 1] - zz[:, 2])
    zb = b0 * (zz[:, 0] - zz[:, 2]) + b1 * (zz[:, 1] - zz[:, 2])
    zc = c0 * (zz[:, 0] - zz[:, 2]) + c1 * (zz[:, 1] - zz[:, 2]) + zz[:, 2]
    return _Triangles(idx, jmin, imin, jmax - jmin + 1, imax - imin + 1, (a0, b0, c0), (a1, b1, c1), (za, zb, zc))


def _fill(tri: _Triangles, start: int, stop: int, counts: np.ndarray, ends: np.ndarray, base: int, width: int,
          zbuf: np.ndarray, fbuf: np.ndarray) -> None:
    """Write triangles ``start``..``stop`` of ``tri`` into the flat buffers: every pixel of their
    boxes inside them, the nearest depth winning."""
    sel = slice(start, stop)
    cnt = counts[sel]
    rep = np.repeat(np.arange(start, stop), cnt)
    offs = np.arange(int(cnt.sum())) - np.repeat(ends[sel] - cnt - base, cnt)
    px = tri.jmin[rep] + offs % tri.w[rep]
    py = tri.imin[rep] + offs // tri.w[rep]
    cx, cy = px + 0.5, py + 0.5
    (a0, b0, c0), (a1, b1, c1), (za, zb, zc) = tri.l0, tri.l1, tri.z
    l0 = a0[rep] * cx + b0[rep] * cy + c0[rep]
    l1 = a1[rep] * cx + b1[rep] * cy + c1[rep]
    eps = -1e-9
    inside = (l0 >= eps) & (l1 >= eps) & (1.0 - l0 - l1 >= eps)
    rep, px, py, cx, cy = rep[inside], px[inside], py[inside], cx[inside], cy[inside]
    zz_c = za[rep] * cx + zb[rep] * cy + zc[rep]
    pix = py * width + px
    order = np.lexsort((zz_c, pix))
    pix, zz_c, rep = pix[order], zz_c[order], rep[order]
    first = np.ones(len(pix), dtype=bool)
    first[1:] = pix[1:] != pix[:-1]
    pix, zz_c, rep = pix[first], zz_c[first], rep[first]
    better = zz_c < zbuf[pix]
    zbuf[pix[better]] = zz_c[better]
    fbuf[pix[better]] = tri.idx[rep[better]]


def look_at(azimuth_deg: float, elevation_deg: float, distance: float) -> tuple[np.ndarray, np.ndarray]:
    """Eye position and world-to-camera rotation (rows: right, up, forward).

    The camera looks at the origin with +Y up; see the module docstring.
    """
    a, e = np.radians(azimuth_deg), np.radians(elevation_deg)
    eye = distance * np.array([np.cos(e) * np.sin(a), np.sin(e), np.cos(e) * np.cos(a)])
    fwd = -eye / np.linalg.norm(eye)
    up = np.array([0.0, 1.0, 0.0])
    right = np.cross(fwd, up)
    if np.linalg.norm(right) < 1e-9:
        right = np.array([1.0, 0.0, 0.0])
    right /= np.linalg.norm(right)
    cam_up = np.cross(right, fwd)
    return eye, np.stack([right, cam_up, fwd])


def _face_normals(tri: np.ndarray) -> np.ndarray:
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    length = np.linalg.norm(n, axis=1, keepdims=True)
    return np.divide(n, length, out=np.zeros_like(n), where=length > 0)


def render(
    mesh: trimesh.Trimesh,
    azimuth_deg: float,
    elevation_deg: float,
    distance: float,
    size: int = 137,
    fov_deg: float = R2N2_FOV_DEG,
    light: tuple[float, float, float] = (-0.4, 0.8, 0.45),
    color: tuple[float, float, float] = (0.7, 0.7, 0.72),
    ambient: float = 0.25,
    supersample: int = 1,
    face_colors: np.ndarray | None = None,
) -> tuple[np.ndarray, dict]:
    """Render ``mesh`` to an RGBA uint8 image with a transparent background.

    ``light`` is a key-light direction in camera space (x right, y up, z towards
    the viewer), added to a headlight; ``supersample`` > 1 anti-aliases.
    ``face_colors`` (F, 3) in [0, 1] colours each face instead of ``color``.
    """
    s = int(size) * int(supersample)
    eye, rot = look_at(azimuth_deg, elevation_deg, distance)
    v = np.asarray(mesh.vertices, dtype=np.float64)
    f = np.asarray(mesh.faces, dtype=np.int64)
    cam = (v - eye) @ rot.T
    focal = 0.5 * s / np.tan(np.radians(fov_deg) / 2.0)
    near = 1e-3
    zc = cam[:, 2]
    keep = (zc[f] > near).all(axis=1)
    f = f[keep]
    per_face = (np.broadcast_to(np.asarray(color, dtype=np.float64), (len(f), 3)) if face_colors is None
                else np.asarray(face_colors, dtype=np.float64)[keep])
    with np.errstate(all="ignore"):
        sx = 0.5 * s + focal * cam[:, 0] / zc
        sy = 0.5 * s - focal * cam[:, 1] / zc
        key = -1.0 / zc
    _, fid = rasterize(np.stack([sx, sy], axis=1), key, f, s, s)
    normals_cam = _face_normals(cam[f])
    l_key = np.asarray(light, dtype=np.float64)
    l_key = l_key / np.linalg.norm(l_key)
    # Camera-space z points away from the viewer: the headlight is -z.
    lam = 0.55 * np.abs(normals_cam[:, 2]) + 0.45 * np.abs(normals_cam @ (l_key * [1, 1, -1]))
    shade = ambient + (1.0 - ambient) * lam
    covered = fid >= 0
    rgb = np.zeros((s, s, 3))
    rgb[covered] = shade[fid[covered], None] * per_face[fid[covered]]
    alpha = covered.astype(np.float64)
    if supersample > 1:
        k = int(supersample)
        rgb = rgb.reshape(size, k, size, k, 3).mean(axis=(1, 3))
        alpha = alpha.reshape(size, k, size, k).mean(axis=(1, 3))
        rgb = np.divide(rgb, alpha[..., None], out=np.zeros_like(rgb), where=alpha[..., None] > 0)
    img = np.zeros((size, size, 4), dtype=np.uint8)
    img[..., :3] = np.clip(np.round(rgb * 255), 0, 255).astype(np.uint8)
    img[..., 3] = np.clip(np.round(alpha * 255), 0, 255).astype(np.uint8)
    camera = {
        "azimuth": float(azimuth_deg),
        "elevation": float(elevation_deg),
        "in_plane_rotation": 0.0,
        "distance": float(distance),
        "fov": float(fov_deg),
    }
    return img, camera


def render_views(
    mesh: trimesh.Trimesh,
    n_views: int = 24,
    rng: np.random.Generator | None = None,
    size: int = 137,
    elevation_range: tuple[float, float] = (25.0, 30.0),
    distance_ratio_range: tuple[float, float] = (0.65, 0.85),
    fov_deg: float = R2N2_FOV_DEG,
    color: tuple[float, float, float] | None = None,
) -> tuple[np.ndarray, list[dict]]:
    """Render ``n_views`` random 3D-R2N2-style views: images (n, size, size, 4).

    Azimuth is uniform in [0, 360), elevation and distance ratio uniform in the
    given ranges (camera distance = ratio * R2N2_MAX_DISTANCE).
    """
    rng = np.random.default_rng() if rng is None else rng
    if color is None:
        color = tuple(0.45 + 0.4 * rng.random(3))
    images = np.zeros((n_views, size, size, 4), dtype=np.uint8)
    cameras = []
    for i in range(n_views):
        az = float(rng.uniform(0.0, 360.0))
        el = float(rng.uniform(*elevation_range))
        dist = float(rng.uniform(*distance_ratio_range)) * R2N2_MAX_DISTANCE
        images[i], cam = render(mesh, az, el, dist, size=size, fov_deg=fov_deg, color=color)
        cameras.append(cam)
    return images, cameras


def metadata_row(camera: dict) -> list[float]:
    """One rendering_metadata.txt row of 3D-R2N2: azimuth, elevation, in-plane
    rotation, distance ratio and field of view."""
    return [
        camera["azimuth"],
        camera["elevation"],
        camera["in_plane_rotation"],
        camera["distance"] / R2N2_MAX_DISTANCE,
        camera["fov"],
    ]


def composite(
    rgba: np.ndarray,
    background: tuple[int, int, int] | None = None,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """Alpha-composite an RGBA image onto a background, returning RGB uint8.

    ``background`` None picks a random solid colour, vertical/horizontal
    gradient or smoothed noise (for robustness training); else a solid RGB.
    """
    rng = np.random.default_rng() if rng is None else rng
    h, w = rgba.shape[:2]
    if background is not None:
        bg = np.broadcast_to(np.asarray(background, dtype=np.float64), (h, w, 3))
    else:
        kind = rng.integers(3)
        if kind == 0:
            bg = np.broadcast_to(rng.uniform(0, 255, 3), (h, w, 3))
        elif kind == 1:
            c0, c1 = rng.uniform(0, 255, 3), rng.uniform(0, 255, 3)
            ramp = np.linspace(0.0, 1.0, h if rng.random() < 0.5 else w)
            ramp = ramp[:, None] if len(ramp) == h else ramp[None, :]
            ramp = np.broadcast_to(ramp, (h, w))[..., None]
            bg = c0 * (1 - ramp) + c1 * ramp
        else:
            cell = int(rng.integers(4, 17))
            coarse = rng.uniform(0, 255, (h // cell + 2, w // cell + 2, 3))
            bg = np.repeat(np.repeat(coarse, cell, axis=0), cell, axis=1)[:h, :w]
            bg = bg + rng.normal(0, 12, (h, w, 3))
    a = rgba[..., 3:4].astype(np.float64) / 255.0
    out = rgba[..., :3].astype(np.float64) * a + bg * (1 - a)
    return np.clip(np.round(out), 0, 255).astype(np.uint8)
