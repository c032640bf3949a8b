"""Part primitives (boxes, frusta, tubes, lofts, ellipsoids) as (vertices, faces).

Every part is a closed triangle mesh built by lofting rings of points; a shape
is the concatenation of its parts (an overlapping polygon soup, like ShapeNet).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import trimesh

Part = tuple[np.ndarray, np.ndarray]


def rot_x(deg: float) -> np.ndarray:
    """Rotation matrix about +X by ``deg`` degrees (right-handed)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[1, 0, 0], [0, c, -s], [0, s, c]])


def rot_y(deg: float) -> np.ndarray:
    """Rotation matrix about +Y by ``deg`` degrees (right-handed)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]])


def rot_z(deg: float) -> np.ndarray:
    """Rotation matrix about +Z by ``deg`` degrees (right-handed)."""
    c, s = np.cos(np.radians(deg)), np.sin(np.radians(deg))
    return np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])


def loft(rings: np.ndarray, cap_start: bool = True, cap_end: bool = True) -> Part:
    """Skin S rings of K points each, shape (S, K, 3), into a closed tube.

    Caps are fans from each end ring's centroid, so end rings should be
    star-shaped about their centroid.
    """
    rings = np.asarray(rings, dtype=np.float64)
    s, k = rings.shape[:2]
    verts = [rings.reshape(-1, 3)]
    i = np.arange(s - 1)[:, None] * k
    j = np.arange(k)[None, :]
    jn = (j + 1) % k
    a, b, c, d = i + j, i + jn, i + k + jn, i + k + j
    faces = [np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)]
    n = s * k
    if cap_start:
        verts.append(rings[0].mean(axis=0, keepdims=True))
        faces.append(np.stack([np.full(k, n), (np.arange(k) + 1) % k, np.arange(k)], -1))
        n += 1
    if cap_end:
        verts.append(rings[-1].mean(axis=0, keepdims=True))
        base = (s - 1) * k
        faces.append(np.stack([np.full(k, n), base + np.arange(k), base + (np.arange(k) + 1) % k], -1))
    return np.concatenate(verts), np.concatenate(faces).astype(np.int64)


def circle(k: int = 12) -> np.ndarray:
    """K points of the unit circle, (K, 2)."""
    t = np.linspace(0, 2 * np.pi, k, endpoint=False)
    return np.stack([np.cos(t), np.sin(t)], axis=1)


def rounded_rect(w: float, h: float, r: float, n: int = 3) -> np.ndarray:
    """Rounded rectangle of size w x h with corner radius r, 4*(n+1) points."""
    r = float(np.clip(r, 0.0, 0.5 * min(w, h) * 0.999))
    pts = []
    centres = [(w / 2 - r, h / 2 - r), (-w / 2 + r, h / 2 - r), (-w / 2 + r, -h / 2 + r), (w / 2 - r, -h / 2 + r)]
    for q, (cx, cy) in enumerate(centres):
        t = np.linspace(0, np.pi / 2, n + 1) + q * np.pi / 2
        pts.append(np.stack([cx + r * np.cos(t), cy + r * np.sin(t)], axis=1))
    return np.concatenate(pts)


def frame(direction: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors orthogonal to ``direction`` (and to each other)."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    helper = np.array([0.0, 1.0, 0.0]) if abs(d[1]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(d, helper)
    u /= np.linalg.norm(u)
    return u, np.cross(d, u)


def sweep(path: np.ndarray, profiles: np.ndarray, caps: bool = True) -> Part:
    """Sweep 2D profiles (S, K, 2) or one profile (K, 2) along a polyline (S, 3).

    Frames are parallel-transported so the tube does not twist.
    """
    path = np.asarray(path, dtype=np.float64)
    s = len(path)
    prof = np.asarray(profiles, dtype=np.float64)
    if prof.ndim == 2:
        prof = np.broadcast_to(prof, (s,) + prof.shape)
    tang = np.gradient(path, axis=0)
    tang /= np.linalg.norm(tang, axis=1, keepdims=True)
    u, _ = frame(tang[0])
    rings = []
    for i in range(s):
        u = u - np.dot(u, tang[i]) * tang[i]
        u /= np.linalg.norm(u)
        v = np.cross(tang[i], u)
        rings.append(path[i] + prof[i][:, :1] * u + prof[i][:, 1:] * v)
    return loft(np.array(rings), caps, caps)


def box(center, size, rot: np.ndarray | None = None) -> Part:
    """Box with the given centre and full edge lengths, optionally rotated about its centre."""
    sx, sy, sz = np.asarray(size, dtype=np.float64) / 2
    ring = np.array([[sx, sy], [-sx, sy], [-sx, -sy], [sx, -sy]])
    rings = np.array([np.c_[ring, np.full(4, -sz)], np.c_[ring, np.full(4, sz)]])
    v, f = loft(rings)
    v = v if rot is None else v @ np.asarray(rot).T
    return v + np.asarray(center, dtype=np.float64), f


def frustum(p0, p1, r0: float, r1: float | None = None, k: int = 12, profile: np.ndarray | None = None) -> Part:
    """Cylinder or cone frustum from p0 (radius r0) to p1 (radius r1)."""
    p0, p1 = np.asarray(p0, dtype=np.float64), np.asarray(p1, dtype=np.float64)
    r1 = r0 if r1 is None else r1
    u, v = frame(p1 - p0)
    c = circle(k) if profile is None else profile
    rings = [p + r * (c[:, :1] * u + c[:, 1:] * v) for p, r in ((p0, r0), (p1, r1))]
    return loft(np.array(rings))


def tube(path, radius: float, k: int = 8) -> Part:
    """Round tube of constant radius along a polyline."""
    return sweep(path, radius * circle(k))


def ellipsoid(center, radii, k: int = 14, s: int = 8, rot: np.ndarray | None = None) -> Part:
    """Ellipsoid from latitude rings (poles closed by the loft caps)."""
    lat = np.linspace(-np.pi / 2, np.pi / 2, s + 2)[1:-1]
    c = circle(k)
    rings = np.array([np.c_[c[:, 0] * np.cos(a), np.full(k, np.sin(a)), c[:, 1] * np.cos(a)] for a in lat])
    v, f = loft(rings * np.asarray(radii, dtype=np.float64))
    # Move the cap centres to the poles so the ellipsoid is round and closed.
    v[-2] = [0.0, -radii[1], 0.0]
    v[-1] = [0.0, radii[1], 0.0]
    v = v if rot is None else v @ np.asarray(rot).T
    return v + np.asarray(center, dtype=np.float64), f


def arc(center, radius: float, a0: float, a1: float, n: int, plane: str = "xy") -> np.ndarray:
    """Points on a circular arc (angles in degrees) in a coordinate plane."""
    t = np.radians(np.linspace(a0, a1, n))
    out = np.zeros((n, 3)) + np.asarray(center, dtype=np.float64)
    i, j = {"xy": (0, 1), "yz": (1, 2), "xz": (0, 2), "zy": (2, 1)}[plane]
    out[:, i] += radius * np.cos(t)
    out[:, j] += radius * np.sin(t)
    return out


@dataclass
class Assembly:
    """Collects parts and turns them into one normalised polygon-soup mesh."""

    parts: list[Part] = field(default_factory=list)

    def add(self, part: Part, mirror_x: bool = False) -> None:
        """Add a part (and its mirror image across x = 0 when ``mirror_x``)."""
        self.parts.append(part)
        if mirror_x:
            v, f = part
            self.parts.append((v * [-1, 1, 1], f[:, ::-1]))

    def mesh(self) -> trimesh.Trimesh:
        """Concatenate parts, centre the bounding box, scale its longest edge to 1."""
        offs = np.cumsum([0] + [len(v) for v, _ in self.parts])
        v = np.concatenate([p[0] for p in self.parts])
        f = np.concatenate([p[1] + o for p, o in zip(self.parts, offs[:-1])])
        lo, hi = v.min(axis=0), v.max(axis=0)
        v = (v - (lo + hi) / 2) / (hi - lo).max()
        return trimesh.Trimesh(vertices=v, faces=f, process=False)
