"""Device generators: display, lamp, loudspeaker, telephone (screens/drivers face +Z)."""

from __future__ import annotations

import numpy as np

from .primitives import Assembly, arc, box, circle, ellipsoid, frustum, loft, rot_x, rounded_rect, sweep, tube


def _lathe(radii, ys, k: int = 16) -> tuple[np.ndarray, np.ndarray]:
    """Surface of revolution about +Y from a radius profile."""
    c = circle(k)
    return loft(np.array([np.c_[c[:, 0] * r, np.full(k, y), c[:, 1] * r] for r, y in zip(radii, ys)]))


def display(rng: np.random.Generator) -> Assembly:
    """Display: flat panel (monitor/TV/all-in-one/CRT) with bezel, neck and base, legs or none."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["monitor", "tv", "aio", "crt"], p=[0.4, 0.25, 0.15, 0.2])
    aspect = float(rng.choice([16 / 9, 16 / 10, 4 / 3, 21 / 9])) if kind != "crt" else u(1.2, 1.4)
    w = u(0.5, 1.0)
    h = w / aspect
    t = u(0.01, 0.04) if kind != "aio" else u(0.03, 0.06)
    lift = u(0.08, 0.2)
    chin = u(0.04, 0.1) if kind == "aio" else 0.0
    yc = lift + (h + chin) / 2
    a.add(box([0, yc, 0], [w, h + chin, t]))
    bz = u(0.005, 0.015)
    fw = u(0.01, 0.04)
    for sx in (-1, 1):
        a.add(box([sx * (w / 2 - fw / 2), yc, t / 2 + bz / 2], [fw, h + chin, bz]))
    a.add(box([0, yc + (h + chin) / 2 - fw / 2, t / 2 + bz / 2], [w, fw, bz]))
    a.add(box([0, lift + chin + fw / 2 if chin else lift + fw / 2, t / 2 + bz / 2], [w, fw + chin, bz]))
    if kind == "crt":
        depth = u(0.3, 0.6) * w
        hw, hh = w * u(0.4, 0.6), h * u(0.4, 0.6)
        r0 = np.c_[rounded_rect(w * 0.95, h * 0.95, 0.02), np.zeros(16)]
        r1 = np.c_[rounded_rect(hw, hh, 0.02), np.zeros(16)]
        rings = np.array([r0 + [0, yc, -t / 2], r1 + [0, yc + u(-0.05, 0.05), -t / 2 - depth]])
        a.add(loft(rings))
        a.add(box([0, lift / 2, -depth * 0.3], [w * 0.6, lift, depth * 0.8]))
        return a
    if kind == "monitor" and rng.random() < 0.3:
        a.add(box([0, yc, -t / 2 - 0.02], [w * 0.4, h * 0.4, 0.04]))
    stand = rng.choice(["neck", "legs", "wall"], p=[0.7, 0.2, 0.1] if kind == "tv" else [0.9, 0.1, 0.0])
    if stand == "neck":
        nw = u(0.03, 0.12)
        nz = -t / 2 - u(0.02, 0.08)
        a.add(box([0, (lift + yc) / 2, nz], [nw, yc - lift / 2 + 0.02, 0.03], rot_x(u(-12, 5))))
        base = rng.choice(["rect", "disc", "v"])
        if base == "rect":
            a.add(box([0, 0.01, nz + 0.03], [u(0.2, 0.5) * w, 0.02, u(0.15, 0.3)]))
        elif base == "disc":
            a.add(frustum([0, 0, nz], [0, 0.02, nz], u(0.1, 0.2), u(0.08, 0.18), k=24))
        else:
            for sx in (-1, 1):
                a.add(box([sx * 0.08, 0.01, nz + 0.06], [0.04, 0.02, 0.22], np.array(
                    [[np.cos(sx * 0.5), 0, np.sin(sx * 0.5)], [0, 1, 0], [-np.sin(sx * 0.5), 0, np.cos(sx * 0.5)]])))
    elif stand == "legs":
        for sx in (-1, 1):
            x = sx * w * u(0.3, 0.45)
            a.add(box([x, lift / 2, 0], [0.02, lift, 0.02]))
            a.add(box([x, 0.01, 0], [0.04, 0.02, u(0.12, 0.2)]))
    return a


def lamp(rng: np.random.Generator) -> Assembly:
    """Lamp: floor/table/desk/pendant/arc/multi-arm styles with cone, drum or dome shades."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["floor", "table", "desk", "pendant", "arc", "multi"], p=[0.2, 0.25, 0.2, 0.15, 0.1, 0.1])

    def shade(top, r_top, r_bot, hh, style=None):
        style = style or rng.choice(["cone", "drum", "dome"])
        top = np.asarray(top, dtype=np.float64)
        if style == "dome":
            ys = np.linspace(0, -hh, 6)
            rs = r_bot * np.sqrt(np.clip(1 - (1 + ys / hh) ** 2, 0.01, 1))
            rs[-1] = r_bot
            v, f = _lathe(rs, ys)
        else:
            rt = r_bot if style == "drum" else r_top
            v, f = _lathe([rt, r_bot], [0, -hh])
        a.add((v + top, f))

    if kind in ("floor", "table"):
        H = u(1.2, 1.8) if kind == "floor" else u(0.45, 0.8)
        br = u(0.1, 0.2) if kind == "floor" else u(0.05, 0.1)
        if kind == "table" and rng.random() < 0.6:
            ys = np.linspace(0, H * u(0.3, 0.45), 8)
            prof = br * (0.5 + 0.5 * np.sin(np.linspace(0.2, np.pi - u(0.2, 0.8), 8)))
            a.add(_lathe(prof, ys))
            a.add(frustum([0, ys[-1], 0], [0, H * 0.8, 0], 0.008, k=8))
        else:
            a.add(frustum([0, 0, 0], [0, 0.03, 0], br, br * 0.9, k=20))
            a.add(frustum([0, 0.03, 0], [0, H * 0.8, 0], u(0.008, 0.02), k=8))
        sr = u(0.1, 0.25) if kind == "floor" else u(0.08, 0.2)
        shade([0, H, 0], sr * u(0.4, 0.8), sr, u(0.12, 0.3) if kind == "floor" else H * u(0.2, 0.35))
    elif kind == "desk":
        br = u(0.06, 0.12)
        a.add(frustum([0, 0, 0], [0, 0.025, 0], br, br * 0.9, k=16) if rng.random() < 0.5
              else box([0, 0.0125, 0], [2 * br, 0.025, 1.5 * br]))
        l1, l2 = u(0.2, 0.4), u(0.2, 0.4)
        a1 = np.radians(u(50, 85))
        j1 = np.array([0, 0.025, -br * 0.5])
        j2 = j1 + l1 * np.array([0, np.sin(a1), np.cos(a1)])
        a2 = np.radians(u(-40, 10))
        j3 = j2 + l2 * np.array([0, np.sin(a2), np.cos(a2)])
        for p, q in ((j1, j2), (j2, j3)):
            a.add(frustum(p, q, 0.008, k=6))
        a.add(ellipsoid(j2, [0.015, 0.015, 0.015], k=8, s=4))
        hr = u(0.04, 0.08)
        v, f = _lathe([hr * 0.3, hr], [0, -u(0.06, 0.12)])
        a.add((v @ rot_x(u(-30, 0)).T + j3, f))
    elif kind == "pendant":
        H = u(0.4, 1.0)
        a.add(frustum([0, H, 0], [0, H - 0.02, 0], u(0.04, 0.08), k=16))
        a.add(frustum([0, H - 0.02, 0], [0, H * u(0.3, 0.6), 0], 0.004, k=6))
        sr = u(0.1, 0.3)
        shade([0, H * 0.45, 0], sr * 0.2, sr, u(0.08, 0.25))
    elif kind == "arc":
        H = u(1.4, 1.9)
        R = u(0.35, 0.6)
        a.add(box([0, 0.03, 0], [0.3, 0.06, 0.3]))
        path = arc([0, H - R, R], R, 180, u(10, 40), 10, plane="zy")
        a.add(tube(np.r_[[[0, 0.06, 0]], path], 0.012, k=6))
        end = path[-1] - [0, 0.02, 0]
        shade(end, 0.04, u(0.12, 0.2), u(0.1, 0.18), "dome")
    else:
        H = u(0.5, 1.0)
        a.add(frustum([0, 0, 0], [0, 0.03, 0], u(0.1, 0.15), k=16))
        a.add(frustum([0, 0.03, 0], [0, H, 0], 0.012, k=8))
        n = int(rng.integers(3, 7))
        ar = u(0.15, 0.35)
        for i in range(n):
            ang = 2 * np.pi * i / n
            d = np.array([np.sin(ang), 0, np.cos(ang)])
            p0 = np.array([0, H * 0.8, 0])
            p1 = p0 + d * ar + [0, u(0.05, 0.15), 0]
            a.add(tube(np.array([p0, p0 + d * ar * 0.6 - [0, 0.05, 0], p1]), 0.007, k=6))
            shade(p1 + [0, 0.08, 0], 0.03, 0.05, 0.08, "cone")
    return a


def loudspeaker(rng: np.random.Generator) -> Assembly:
    """Loudspeaker: tower/bookshelf/sub/PA/cylinder/soundbar cabinet with 1-4 drivers, port, feet."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["tower", "bookshelf", "sub", "pa", "cylinder", "bar"], p=[0.25, 0.25, 0.15, 0.15, 0.1, 0.1])
    if kind == "cylinder":
        r, H = u(0.08, 0.15), u(0.2, 0.5)
        a.add(frustum([0, 0, 0], [0, H, 0], r, r * u(0.85, 1.0), k=24))
        a.add(frustum([0, H, 0], [0, H + 0.01, 0], r * 0.9, r * 0.7, k=24))
        return a
    w, h, d = {
        "tower": (u(0.18, 0.3), u(0.8, 1.2), u(0.22, 0.38)),
        "bookshelf": (u(0.15, 0.25), u(0.25, 0.4), u(0.18, 0.3)),
        "sub": (u(0.3, 0.45), u(0.3, 0.45), u(0.3, 0.45)),
        "pa": (u(0.3, 0.45), u(0.5, 0.8), u(0.3, 0.45)),
        "bar": (u(0.8, 1.1), u(0.06, 0.1), u(0.08, 0.12)),
    }[kind]
    feet = u(0.0, 0.05) if kind in ("tower", "sub") else 0.0
    if kind == "pa":
        back = np.c_[rounded_rect(w * 0.6, h * 0.9, 0.01), np.zeros(16)]
        front = np.c_[rounded_rect(w, h, 0.01), np.zeros(16)]
        a.add(loft(np.array([back + [0, h / 2, -d / 2], front + [0, h / 2, d / 2]])))
    else:
        r = min(w, h, d) * 0.08
        prof = rounded_rect(w, h, r)
        a.add(loft(np.array([np.c_[prof, np.full(16, z)] + [0, h / 2 + feet, 0] for z in (-d / 2, d / 2)])))
    if kind == "bar":
        n_drv = int(rng.integers(2, 5))
        for i in range(n_drv):
            x = -w * 0.4 + w * 0.8 * (i + 0.5) / n_drv
            a.add(frustum([x, h / 2, d / 2 - 0.01], [x, h / 2, d / 2 + 0.005], h * 0.35, h * 0.3, k=12))
        return a
    n_drv = {"tower": int(rng.integers(2, 5)), "bookshelf": int(rng.integers(1, 3)), "sub": 1,
             "pa": int(rng.integers(1, 3))}[kind]
    rad = [min(w, h / n_drv) * 0.18] + [min(w, h / n_drv) * u(0.3, 0.42)] * (n_drv - 1)
    if kind == "sub":
        rad = [min(w, h) * u(0.26, 0.36)]
    slots = [h / 2 + feet] if kind == "sub" else []
    prev_y = prev_r = 0.0                      # the driver above; set by each iteration
    for i, rr in enumerate(rad):
        if not slots:
            y = h + feet - rr - 0.03
        else:
            y = slots[0]
        if i > 0 and kind != "sub":
            y = prev_y - prev_r - rr - 0.02
        lip = max(0.012, rr * 0.12)
        a.add(frustum([0, y, d / 2 - 0.01], [0, y, d / 2 + lip], rr * 1.12, rr * 1.0, k=20))
        a.add(frustum([0, y, d / 2 + lip * 0.9], [0, y, d / 2 + lip * 0.2], rr * 0.98, rr * 0.3, k=20))
        a.add(ellipsoid([0, y, d / 2 + lip * 0.2], [rr * 0.25, rr * 0.25, rr * 0.12], k=10, s=4))
        prev_y, prev_r = y, rr
    if rng.random() < 0.5 and kind != "sub":
        py = max(feet + 0.05, prev_y - prev_r - 0.06)
        a.add(frustum([0, py, d / 2 - 0.03], [0, py, d / 2 + 0.004], 0.025, k=14))
    if feet > 0.01:
        for sz in (-1, 1):
            a.add(frustum([w / 2 - 0.03, 0, sz * (d / 2 - 0.03)], [w / 2 - 0.03, feet, sz * (d / 2 - 0.03)], 0.008,
                          0.02, k=8), mirror_x=True)
    if kind == "pa" and rng.random() < 0.5:
        a.add(box([0, h + 0.02, 0], [w * 0.4, 0.03, 0.04]))
    return a


def telephone(rng: np.random.Generator) -> Assembly:
    """Telephone: smartphone slab, keypad phone, flip phone or desk phone with handset."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["smart", "keypad", "flip", "desk"], p=[0.45, 0.2, 0.15, 0.2])

    def slab(center, w, h, t, r, rot=None):
        prof = rounded_rect(w, h, r)
        v, f = loft(np.array([np.c_[prof, np.full(16, z)] for z in (-t / 2, t / 2)]))
        v = v if rot is None else v @ np.asarray(rot).T
        a.add((v + center, f))

    if kind == "smart":
        w, h, t = u(0.06, 0.09), u(0.12, 0.17), u(0.007, 0.012)
        slab([0, 0, 0], w, h, t, u(0.004, 0.012))
        a.add(box([0, 0, t / 2 + 0.0005], [w * 0.92, h * 0.86, 0.001]))
        a.add(box([w * u(-0.3, 0.2), h * 0.38, -t / 2 - 0.001], [u(0.012, 0.03), u(0.012, 0.03), 0.002]))
        a.add(box([w / 2 + 0.0005, h * 0.2, 0], [0.001, 0.02, t * 0.4]))
    elif kind == "keypad":
        w, h, t = u(0.045, 0.06), u(0.1, 0.14), u(0.015, 0.025)
        slab([0, 0, 0], w, h, t, u(0.005, 0.015))
        a.add(box([0, h * 0.22, t / 2 + 0.001], [w * 0.75, h * 0.35, 0.002]))
        for i in range(4):
            for j in range(3):
                a.add(box([(j - 1) * w * 0.28, -h * 0.05 - i * h * 0.1, t / 2 + 0.002], [w * 0.2, h * 0.06, 0.004]))
        if rng.random() < 0.3:
            a.add(frustum([w * 0.3, h / 2, 0], [w * 0.3, h / 2 + u(0.02, 0.05), 0], 0.004, k=6))
    elif kind == "flip":
        w, h, t = u(0.045, 0.055), u(0.08, 0.1), u(0.01, 0.014)
        slab([0, -h / 2, 0], w, h, t, 0.008)
        ang = u(140, 170)
        R = rot_x(-(180 - ang))
        slab(np.array([0, 0, 0]) + R @ np.array([0, h / 2, 0]), w, h, t, 0.008, R)
        a.add(frustum([-w / 2, 0, 0], [w / 2, 0, 0], t * 0.6, k=10))
        for i in range(4):
            for j in range(3):
                a.add(box([(j - 1) * w * 0.28, -h * 0.3 - i * h * 0.12, t / 2 + 0.002], [w * 0.2, h * 0.07, 0.004]))
    else:
        bw, bd = u(0.16, 0.24), u(0.16, 0.24)
        bh0, bh1 = u(0.03, 0.05), u(0.06, 0.1)
        base = np.array([[bw / 2, 0], [bw / 2, bh0], [-bw / 2, bh0], [-bw / 2, 0]])
        back = np.array([[bw / 2, 0], [bw / 2, bh1], [-bw / 2, bh1], [-bw / 2, 0]])
        a.add(loft(np.array([np.c_[back, np.full(4, -bd / 2)], np.c_[base, np.full(4, bd / 2)]])))
        hl = u(0.18, 0.24)
        y = bh1 + 0.015
        z = -bd / 2 + 0.04
        path = np.array([[-hl / 2, y + 0.02, z], [-hl / 3, y, z], [hl / 3, y, z], [hl / 2, y + 0.02, z]])
        a.add(sweep(path, rounded_rect(0.025, 0.035, 0.008)[:, ::-1]))
        for sx in (-1, 1):
            a.add(ellipsoid([sx * hl / 2, y + 0.02, z], [0.025, 0.02, 0.03], k=10, s=5))
        slope = np.degrees(np.arctan2(bh1 - bh0, bd))
        for i in range(4):
            for j in range(3):
                zz = bd / 2 - 0.03 - i * 0.025
                yy = bh0 + (bd / 2 - zz) * np.tan(np.radians(slope)) + 0.003
                a.add(box([(j - 1) * 0.025 + bw * 0.15, yy, zz], [0.018, 0.006, 0.016], rot_x(-slope)))
        if rng.random() < 0.5:
            a.add(box([-bw * 0.25, bh0 + 0.02, bd * 0.1], [bw * 0.3, 0.003, bd * 0.3], rot_x(-slope)))
    return a


__all__ = ["display", "lamp", "loudspeaker", "telephone"]
