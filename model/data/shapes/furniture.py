"""Furniture generators: bench, cabinet, chair, sofa, table.

Each takes a NumPy Generator and returns an Assembly in metres-like units
(+Y up, front +Z, floor at y = 0); ``generate`` normalises it.
"""

from __future__ import annotations

import numpy as np

from .primitives import Assembly, box, frustum, loft, rot_x, rounded_rect, tube


def _legs4(a: Assembly, rng, w: float, d: float, h: float, inset: float, t: float, round_: bool, splay: float) -> None:
    """Four legs from the floor to height h under a w x d footprint."""
    for sz in (-1, 1):
        top = np.array([w / 2 - inset, h, sz * (d / 2 - inset)])
        bottom = top + [splay, -h, sz * splay]
        bottom[1] = 0.0
        if round_:
            a.add(frustum(bottom, top, t * 0.4, t * 0.55, k=10), mirror_x=True)
        else:
            a.add(frustum(bottom, top, t * 0.6, t * 0.7, k=4), mirror_x=True)


def _star_base(a: Assembly, rng, y_top: float, radius: float, t: float, n: int, casters: bool) -> None:
    """Office-chair style pedestal: column plus n radial feet."""
    a.add(frustum([0, 0.05, 0], [0, y_top, 0], t * 0.5, t * 0.4, k=12))
    for i in range(n):
        ang = 2 * np.pi * i / n + np.pi / n
        tip = np.array([radius * np.sin(ang), 0.04, radius * np.cos(ang)])
        a.add(frustum([0, 0.07, 0], tip, t * 0.35, t * 0.2, k=6))
        if casters:
            a.add(frustum(tip - [0, 0.04, 0], tip, t * 0.3, t * 0.3, k=8))


def _seat(a: Assembly, rng, w: float, d: float, h: float, ts: float, z: float = 0.0) -> None:
    """A w x d seat of thickness ts whose top is at height h: a slab, or rounded (40%)."""
    if rng.random() < 0.4:
        v, f = loft([np.c_[rounded_rect(w, d, rng.uniform(0.02, 0.12)), np.full(16, y)][:, [0, 2, 1]]
                     for y in (h - ts, h)])
        a.add((v + [0, 0, z], f))
    else:
        a.add(box([0, h - ts / 2, z], [w, ts, d]))


def chair(rng: np.random.Generator) -> Assembly:
    """Chair: seat, back (solid/slats/frame), legs (4/pedestal/sled), optional arms."""
    a = Assembly()
    u = rng.uniform
    w, d = u(0.38, 0.62), u(0.38, 0.6)
    h = u(0.36, 0.52)
    ts = u(0.025, 0.09)
    back_h = u(0.25, 0.65)
    tilt = u(-2, 18)
    leg_t = u(0.025, 0.06)
    _seat(a, rng, w, d, h, ts)
    # Back, rotated about the seat's rear edge.
    pivot = np.array([0, h, -d / 2 + 0.02])
    R = rot_x(-tilt)
    bt = u(0.02, 0.07)
    style = rng.choice(["solid", "vslats", "hslats", "frame"], p=[0.4, 0.25, 0.15, 0.2])
    post_w = u(0.02, 0.05)

    def put(center, size):
        c = pivot + R @ np.asarray(center)
        a.add(box(c, size, R))

    if style == "solid":
        bw = w * u(0.8, 1.0)
        put([0, back_h / 2, 0], [bw, back_h, bt])
    else:
        for sx in (-1, 1):
            put([sx * (w / 2 - post_w / 2), back_h / 2, 0], [post_w, back_h, bt])
        rail = u(0.04, 0.12)
        put([0, back_h - rail / 2, 0], [w, rail, bt])
        if style == "vslats":
            n = int(rng.integers(2, 7))
            sw = (w - 2 * post_w) / (2 * n + 1)
            for i in range(n):
                x = -w / 2 + post_w + sw * (2 * i + 1.5)
                put([x, (back_h - rail) / 2 + 0.05, 0], [sw, back_h - rail - 0.1, bt * 0.6])
            put([0, 0.05, 0], [w, 0.05, bt])
        elif style == "hslats":
            n = int(rng.integers(2, 5))
            for i in range(n):
                y = (back_h - rail) * (i + 0.6) / (n + 0.3)
                put([0, y, 0], [w, u(0.03, 0.07), bt * 0.6])
        else:
            put([0, back_h * u(0.3, 0.6), 0], [w, rail * 0.7, bt])
    legs = rng.choice(["four", "pedestal", "sled"], p=[0.6, 0.25, 0.15])
    if legs == "four":
        _legs4(a, rng, w, d, h - ts, u(0.0, 0.05), leg_t, rng.random() < 0.5, u(0, 0.04) * (rng.random() < 0.4))
        if rng.random() < 0.4:
            ys = u(0.08, 0.2)
            a.add(box([w / 2 - 0.03, ys, 0], [0.02, 0.02, d - 0.06]), mirror_x=True)
            a.add(box([0, ys, 0], [w - 0.06, 0.02, 0.02]))
    elif legs == "pedestal":
        _star_base(a, rng, h - ts, u(0.22, 0.34), u(0.04, 0.08), int(rng.choice([4, 5, 5])), rng.random() < 0.7)
    else:
        rt = u(0.01, 0.02)
        for sx in (-1, 1):
            x = sx * (w / 2 - 0.02)
            path = np.array([[x, h - ts, d / 2 - 0.04], [x, 0.01, d / 2], [x, 0.01, -d / 2], [x, h - ts, -d / 2 + 0.04]])
            a.add(tube(path, rt))
    if rng.random() < 0.4:
        arm_h = u(0.15, 0.28)
        aw = u(0.03, 0.09)
        for sx in (-1, 1):
            x = sx * (w / 2 + aw / 2 * (rng.random() < 0.5))
            a.add(box([x, h + arm_h, 0.0], [aw, 0.03, d * u(0.7, 0.95)]))
            a.add(box([x, h + arm_h / 2, d * 0.35], [0.025, arm_h, 0.025]))
    return a


def table(rng: np.random.Generator) -> Assembly:
    """Table: rectangular/round/oval top on 4 legs, pedestal, trestle or panels."""
    a = Assembly()
    u = rng.uniform
    h = u(0.35, 0.95) if rng.random() < 0.4 else u(0.68, 0.78)
    t = u(0.02, 0.07)
    shape = rng.choice(["rect", "round", "oval"], p=[0.6, 0.25, 0.15])
    if shape == "rect":
        w, d = u(0.5, 1.8), u(0.45, 1.0)
        a.add(box([0, h - t / 2, 0], [w, t, d]))
    else:
        r = u(0.3, 0.65)
        w, d = (2 * r, 2 * r) if shape == "round" else (2 * r * u(1.3, 2.0), 2 * r)
        prof = np.c_[np.cos(np.linspace(0, 2 * np.pi, 32, endpoint=False)) * w / 2,
                     np.sin(np.linspace(0, 2 * np.pi, 32, endpoint=False)) * d / 2]
        a.add(loft([np.c_[prof[:, 0], np.full(32, y), prof[:, 1]] for y in (h - t, h)]))
    legs = rng.choice(["four", "pedestal", "trestle", "panels"], p=[0.5, 0.2, 0.15, 0.15])
    inner = 0.7 if shape != "rect" else 1.0
    if legs == "four":
        lt = u(0.03, 0.08)
        ins = u(0.02, 0.1)
        _legs4(a, rng, w * inner, d * inner, h - t, ins, lt, rng.random() < 0.5, 0.0)
        if rng.random() < 0.5:
            ah = u(0.04, 0.1)
            a.add(box([w * inner / 2 - ins, h - t - ah / 2, 0], [0.02, ah, d * inner - 2 * ins]), mirror_x=True)
            a.add(box([0, h - t - ah / 2, d * inner / 2 - ins], [w * inner - 2 * ins, ah, 0.02]))
            a.add(box([0, h - t - ah / 2, -d * inner / 2 + ins], [w * inner - 2 * ins, ah, 0.02]))
        if rng.random() < 0.3:
            a.add(box([0, u(0.08, 0.2), 0], [w * inner - 2 * ins, 0.02, d * inner - 2 * ins]))
    elif legs == "pedestal":
        col = u(0.04, 0.12)
        a.add(frustum([0, 0, 0], [0, h - t, 0], col * u(0.6, 1.4), col, k=14))
        if rng.random() < 0.5:
            a.add(frustum([0, 0, 0], [0, 0.03, 0], min(w, d) * u(0.2, 0.35), min(w, d) * 0.15, k=24))
        else:
            n = int(rng.choice([3, 4]))
            for i in range(n):
                ang = 2 * np.pi * i / n
                a.add(frustum([0, 0.03, 0], [0.35 * w * np.sin(ang), 0.02, 0.35 * d * np.cos(ang)], 0.03, 0.02, k=6))
    elif legs == "trestle":
        x = w * inner / 2 - u(0.05, 0.2)
        pw = u(0.04, 0.1)
        a.add(box([x, (h - t) / 2, 0], [pw, h - t, 0.05]), mirror_x=True)
        a.add(box([x, 0.025, 0], [pw, 0.05, d * inner * 0.8]), mirror_x=True)
        a.add(box([x, h - t - 0.03, 0], [pw, 0.05, d * inner * 0.8]), mirror_x=True)
        a.add(box([0, u(0.1, 0.4) * h, 0], [2 * x, 0.05, 0.04]))
    else:
        pt = u(0.02, 0.05)
        a.add(box([w * inner / 2 - pt / 2, (h - t) / 2, 0], [pt, h - t, d * inner * u(0.8, 1.0)]), mirror_x=True)
        if rng.random() < 0.5:
            a.add(box([0, h * 0.6, -d * inner * 0.4], [w * inner - 2 * pt, h * 0.6, pt]))
        if rng.random() < 0.4:
            dw = u(0.3, 0.5)
            a.add(box([w * inner / 2 - pt - dw / 2, (h - t) / 2, 0], [dw, h - t, d * inner * 0.9]))
    return a


def bench(rng: np.random.Generator) -> Assembly:
    """Bench: long (slatted or solid) seat, legs/panels/A-frames, optional back and arms."""
    a = Assembly()
    u = rng.uniform
    L, d = u(0.8, 2.2), u(0.28, 0.6)
    h = u(0.38, 0.5)
    t = u(0.03, 0.07)
    if rng.random() < 0.5:
        n = int(rng.integers(3, 7))
        sd = d / (n * 1.3)
        for i in range(n):
            a.add(box([0, h - t / 2, -d / 2 + sd / 2 + i * (d - sd) / (n - 1)], [L, t, sd]))
        a.add(box([L / 2 - 0.1, h - t - 0.02, 0], [0.05, 0.04, d]), mirror_x=True)
    else:
        a.add(box([0, h - t / 2, 0], [L, t, d]))
    legs = rng.choice(["four", "panels", "aframe"], p=[0.4, 0.3, 0.3])
    x = L / 2 - u(0.05, 0.25)
    if legs == "four":
        _legs4(a, rng, 2 * x + 0.1, d, h - t, 0.05, u(0.03, 0.07), rng.random() < 0.4, 0.0)
        if rng.random() < 0.5:
            a.add(box([0, h * 0.3, 0], [2 * x, 0.03, 0.03]))
    elif legs == "panels":
        a.add(box([x, (h - t) / 2, 0], [u(0.03, 0.08), h - t, d * u(0.7, 1.0)]), mirror_x=True)
    else:
        rt = u(0.01, 0.025)
        for sz in (-1, 1):
            a.add(tube(np.array([[x, h - t, sz * d * 0.3], [x, 0.0, sz * d * 0.5]]), rt, k=6), mirror_x=True)
        a.add(tube(np.array([[x, 0.01, -d * 0.5], [x, 0.01, d * 0.5]]), rt, k=6), mirror_x=True)
    if rng.random() < 0.55:
        bh = u(0.2, 0.45)
        tilt = u(0, 20)
        R = rot_x(-tilt)
        pivot = np.array([0, h, -d / 2 + 0.03])
        n = int(rng.integers(1, 5))
        for i in range(n):
            c = pivot + R @ np.array([0, bh * (i + 0.5) / n, 0])
            a.add(box(c, [L, bh / n * u(0.5, 0.95), 0.03], R))
        a.add(box(pivot + R @ np.array([x, bh / 2, -0.02]), [0.04, bh, 0.03], R), mirror_x=False)
        a.add(box(pivot + R @ np.array([-x, bh / 2, -0.02]), [0.04, bh, 0.03], R))
        if rng.random() < 0.5:
            ah = u(0.15, 0.25)
            a.add(box([L / 2 - 0.03, h + ah, 0], [0.05, 0.03, d]), mirror_x=True)
            a.add(box([L / 2 - 0.03, h + ah / 2, d * 0.4], [0.03, ah, 0.03]), mirror_x=True)
    return a


def sofa(rng: np.random.Generator) -> Assembly:
    """Sofa: base, back, 0-2 arms, 1-4 seat and back cushions, feet, optional chaise."""
    a = Assembly()
    u = rng.uniform
    L, d = u(0.9, 2.6), u(0.7, 1.0)
    feet = u(0.0, 0.15)
    base_h = u(0.15, 0.3)
    back_h = u(0.35, 0.65)
    bt = u(0.12, 0.25)
    a.add(box([0, feet + base_h / 2, 0], [L, base_h, d]))
    a.add(box([0, feet + (base_h + back_h) / 2, -d / 2 + bt / 2], [L, base_h + back_h, bt], rot_x(-u(0, 8))))
    n_arms = int(rng.choice([0, 1, 2, 2, 2, 2]))
    arm_w = u(0.08, 0.25)
    arm_h = u(0.15, 0.35)
    style = rng.choice(["box", "round"])
    for i in range(n_arms):
        sx = 1 if i == 0 else -1
        x = sx * (L / 2 - arm_w / 2)
        if style == "box":
            a.add(box([x, feet + (base_h + arm_h) / 2, 0], [arm_w, base_h + arm_h, d]))
        else:
            a.add(box([x, feet + (base_h + arm_h) / 2 - arm_w / 4, 0], [arm_w, base_h + arm_h - arm_w / 2, d]))
            a.add(frustum([x, feet + base_h + arm_h - arm_w / 2, -d / 2], [x, feet + base_h + arm_h - arm_w / 2, d / 2],
                          arm_w / 2, k=12))
    inner = L - n_arms * arm_w
    n_cush = int(rng.integers(1, 5))
    ch = u(0.06, 0.15)
    cw = inner / n_cush
    for i in range(n_cush):
        x = -inner / 2 + cw * (i + 0.5) + (arm_w / 2 if n_arms == 1 else 0)
        v, f = loft([np.c_[rounded_rect(cw * 0.97, d - bt, 0.04), np.full(16, y)][:, [0, 2, 1]] for y in (0, ch)])
        a.add((v + [x, feet + base_h, bt / 2], f))
        if rng.random() < 0.7:
            a.add(box([x, feet + base_h + ch + back_h * 0.4, -d / 2 + bt + 0.06], [cw * 0.95, back_h * 0.75, 0.12],
                      rot_x(-10)))
    if rng.random() < 0.25:
        cd = u(0.5, 0.8)
        x = L / 2 - u(0.5, 0.8) / 2 - (arm_w if n_arms else 0)
        a.add(box([x, feet + base_h / 2, d / 2 + cd / 2], [u(0.5, 0.8), base_h, cd]))
        a.add(box([x, feet + base_h + ch / 2, d / 2 + cd / 2], [u(0.5, 0.7), ch, cd]))
    if feet > 0.02:
        for sz in (-1, 1):
            a.add(frustum([L / 2 - 0.06, 0, sz * (d / 2 - 0.06)], [L / 2 - 0.06, feet, sz * (d / 2 - 0.06)], 0.02, 0.03,
                          k=8), mirror_x=True)
    return a


def cabinet(rng: np.random.Generator) -> Assembly:
    """Cabinet: carcass (tall/low/cube), doors or drawers with handles, plinth or legs, open shelves."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["tall", "low", "cube", "chest"])
    w, h, d = {
        "tall": (u(0.5, 1.2), u(1.3, 2.1), u(0.35, 0.65)),
        "low": (u(0.9, 2.0), u(0.5, 0.95), u(0.35, 0.55)),
        "cube": (u(0.4, 0.7), u(0.45, 0.8), u(0.35, 0.55)),
        "chest": (u(0.5, 1.0), u(0.7, 1.3), u(0.4, 0.6)),
    }[kind]
    base = u(0.0, 0.2) if rng.random() < 0.5 else 0.0
    t = u(0.015, 0.04)
    open_front = rng.random() < 0.2
    if open_front:
        a.add(box([w / 2 - t / 2, base + h / 2, 0], [t, h, d]), mirror_x=True)
        a.add(box([0, base + h / 2, -d / 2 + t / 2], [w, h, t]))
        n = int(rng.integers(2, 6))
        for i in range(n + 1):
            a.add(box([0, base + t / 2 + i * (h - t) / n, 0], [w - 2 * t, t, d - t]))
    else:
        a.add(box([0, base + h / 2, 0], [w, h, d]))
        if rng.random() < 0.5:
            a.add(box([0, base + h + 0.01, 0.01], [w + 0.04, 0.02, d + 0.02]))
        nx = int(rng.integers(1, 4)) if kind != "cube" else 1
        ny = int(rng.integers(1, 3)) if kind != "chest" else int(rng.integers(3, 7))
        gap = 0.006
        cw, chh = w / nx, h / ny
        handle = rng.choice(["bar", "knob", "none"], p=[0.5, 0.3, 0.2])
        for i in range(nx):
            for j in range(ny):
                cx, cy = -w / 2 + cw * (i + 0.5), base + chh * (j + 0.5)
                a.add(box([cx, cy, d / 2 + 0.008], [cw - 2 * gap, chh - 2 * gap, 0.016]))
                if handle == "bar":
                    if ny > 2 or kind == "low" and rng.random() < 0.5:
                        a.add(box([cx, cy + chh * 0.3, d / 2 + 0.03], [cw * 0.3, 0.015, 0.015]))
                    else:
                        a.add(box([cx + (cw * 0.38 if i % 2 == 0 else -cw * 0.38), cy, d / 2 + 0.03],
                                  [0.015, min(chh * 0.3, 0.25), 0.015]))
                elif handle == "knob":
                    a.add(frustum([cx, cy + chh * 0.25, d / 2 + 0.016], [cx, cy + chh * 0.25, d / 2 + 0.04], 0.012,
                                  0.018, k=8))
    if base > 0:
        if rng.random() < 0.5:
            a.add(box([0, base / 2, 0], [w - 0.04, base, d - 0.04]))
        else:
            _legs4(a, rng, w, d, base, 0.04, u(0.03, 0.06), rng.random() < 0.5, 0.0)
    return a


CHAIR_KINDS = {"folding": 0.1, "panel": 0.1, "cantilever": 0.1, "club": 0.1}
"""The second generator's chair sub-types and their shares (the rest: :func:`chair`'s)."""


def chair_wider(rng: np.random.Generator) -> Assembly:
    """Chair of the second generator: :func:`chair`'s kinds, or (:data:`CHAIR_KINDS`) a folding
    chair, a chair whose sides are slabs to the floor, a cantilever tube frame or an upholstered
    club armchair -- the kinds real chairs showed the first generator lacking."""
    x = rng.random()
    for kind, share in CHAIR_KINDS.items():
        if x < share:
            return _CHAIR_KINDS[kind](rng)
        x -= share
    return chair(rng)


def _folding_chair(rng: np.random.Generator) -> Assembly:
    """Folding chair: thin seat on crossed tube legs, rear legs running up into the back posts,
    a back panel between the posts' tops, stretchers at the feet."""
    a = Assembly()
    u = rng.uniform
    w, d, h = u(0.38, 0.48), u(0.36, 0.46), u(0.4, 0.48)
    back_h, lean, splay = u(0.3, 0.45), u(0.03, 0.1), u(0.04, 0.12)
    r = u(0.008, 0.016)
    ts = u(0.015, 0.04)
    _seat(a, rng, w, d, h, ts)
    x = w / 2 + r
    rear = np.array([[x, 0.0, -d / 2 + 0.05 - splay], [x, h, -d / 2 + 0.02], [x, h + back_h, -d / 2 - lean]])
    a.add(tube(rear, r, k=6), mirror_x=True)
    a.add(tube(np.array([[x + 2 * r, 0.0, d / 2 + splay * 0.6], [x + 2 * r, h - ts, -d / 2 + 0.06]]), r, k=6),
          mirror_x=True)
    ph = back_h * u(0.25, 0.5)
    top = (rear[1] + (rear[2] - rear[1]) * (1 - ph / back_h / 2 - u(0.0, 0.1))) * [0, 1, 1]
    a.add(box(top, [2 * x, ph, u(0.01, 0.025)], rot_x(-np.degrees(np.arctan2(lean, back_h)))))
    for z in (-d / 2 + 0.05 - splay, d / 2 + splay * 0.6):
        a.add(tube(np.array([[-x, 0.02, z], [x, 0.02, z]]), r * 0.8, k=6))
    return a


def _panel_chair(rng: np.random.Generator) -> Assembly:
    """Chair whose sides are slabs (to the floor, or on a front and a rear leg) or posts, the two
    sides alike or not, often with arms on them; a seat between and a slab back, which may
    reach down below the seat."""
    a = Assembly()
    u = rng.uniform
    w, d, h = u(0.42, 0.62), u(0.42, 0.62), u(0.36, 0.48)
    pt, ts = u(0.02, 0.06), u(0.03, 0.08)
    arm_h = h + u(0.12, 0.28) if rng.random() < 0.7 else h - ts
    gap = u(0.08, 0.25) if rng.random() < 0.4 else 0.0
    sides = ["slab", "slab"] if rng.random() < 0.6 else list(rng.choice(["slab", "posts"], 2))
    for sx, side in zip((-1, 1), sides):
        x = sx * (w / 2 + pt / 2)
        if side == "slab":
            a.add(box([x, (gap + arm_h) / 2, 0], [pt, arm_h - gap, d]))
            legs = [(gap / 2, gap)] if gap > 0 else []
        else:
            legs = [(arm_h / 2, arm_h)]
            if arm_h > h:
                a.add(box([x, h - ts - 0.03, 0], [pt, 0.04, d]))
        for y, height in legs:
            for z in (-1, 1):
                a.add(box([x, y, z * (d / 2 - pt)], [pt, height, 2 * pt if height == gap else pt]))
        if arm_h > h:
            a.add(box([x, arm_h + 0.015, u(0.0, 0.06)], [pt * u(1.0, 2.5), 0.03, d * u(0.9, 1.15)]))
    _seat(a, rng, w, d, h, ts)
    tilt, back_h = u(0, 15), u(0.3, 0.6)
    below = h * u(0.3, 1.0) if rng.random() < 0.35 else 0.0
    pivot = np.array([0, h, -d / 2 + 0.02])
    a.add(box(pivot + rot_x(-tilt) @ np.array([0, (back_h - below) / 2, 0]),
              [w * u(0.6, 1.0), back_h + below, u(0.02, 0.05)], rot_x(-tilt)))
    return a


def _cantilever_chair(rng: np.random.Generator) -> Assembly:
    """Cantilever chair: one bent tube per side (floor runner, front upright, under the seat to
    the rear, up the back), seat and back as panels on the frame."""
    a = Assembly()
    u = rng.uniform
    w, d, h = u(0.4, 0.5), u(0.4, 0.52), u(0.4, 0.48)
    back_h, lean, r = u(0.3, 0.48), u(0.02, 0.12), u(0.009, 0.018)
    ts = u(0.02, 0.06)
    x = w / 2 - r
    front = d / 2 - u(0.0, 0.06)
    path = np.array([[x, r, -d / 2 + u(0.0, 0.1)], [x, r, front], [x, h - ts - r, front - u(0.06, 0.14)],
                     [x, h - ts - r, -d / 2 + 0.03], [x, h + back_h, -d / 2 - lean]])
    a.add(tube(path, r, k=6), mirror_x=True)
    _seat(a, rng, w, d, h, ts)
    bh = back_h * u(0.4, 0.8)
    c = path[3] + (path[4] - path[3]) * (1 - bh / back_h / 2)
    a.add(box([0, c[1], c[2] - 0.01], [w, bh, u(0.015, 0.035)], rot_x(-np.degrees(np.arctan2(lean, back_h)))))
    return a


def _club_chair(rng: np.random.Generator) -> Assembly:
    """Upholstered armchair: a low box base, thick arms and back, a seat cushion, short feet."""
    a = Assembly()
    u = rng.uniform
    w, d = u(0.65, 0.95), u(0.65, 0.9)
    feet, base_h = u(0.0, 0.12), u(0.18, 0.3)
    arm_w, arm_h = u(0.1, 0.22), u(0.15, 0.3)
    bt, back_h = u(0.12, 0.22), u(0.3, 0.55)
    a.add(box([0, feet + base_h / 2, 0], [w, base_h, d]))
    a.add(box([0, feet + (base_h + back_h) / 2, -d / 2 + bt / 2], [w, base_h + back_h, bt], rot_x(-u(0, 10))))
    for sx in (-1, 1):
        a.add(box([sx * (w / 2 - arm_w / 2), feet + (base_h + arm_h) / 2, 0.0], [arm_w, base_h + arm_h, d]))
    ch = u(0.06, 0.14)
    a.add(box([0, feet + base_h + ch / 2, bt / 2], [w - 2 * arm_w, ch, d - bt]))
    if feet > 0.02:
        for sz in (-1, 1):
            a.add(frustum([w / 2 - 0.06, 0, sz * (d / 2 - 0.06)], [w / 2 - 0.06, feet, sz * (d / 2 - 0.06)],
                          0.02, 0.03, k=8), mirror_x=True)
    return a


_CHAIR_KINDS = {"folding": _folding_chair, "panel": _panel_chair, "cantilever": _cantilever_chair,
                "club": _club_chair}

__all__ = ["CHAIR_KINDS", "bench", "cabinet", "chair", "chair_wider", "sofa", "table"]
