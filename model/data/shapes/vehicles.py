"""Vehicle-like generators: airplane, car, rifle, watercraft (front/nose/muzzle/bow at +Z)."""

from __future__ import annotations

import numpy as np

from .primitives import Assembly, box, circle, ellipsoid, frustum, loft, rot_x, rounded_rect, sweep, tube


def wing(root, span_dir, span: float, c_root: float, c_tip: float, sweep_deg: float, thick: float, n: int = 3,
         k: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Lofted wing/fin: sections with chord along -Z from the leading edge, spanning along ``span_dir``."""
    root = np.asarray(root, dtype=np.float64)
    sd = np.asarray(span_dir, dtype=np.float64)
    sd /= np.linalg.norm(sd)
    nrm = np.cross([0.0, 0.0, 1.0], sd)
    nrm /= np.linalg.norm(nrm)
    th = np.linspace(0, 2 * np.pi, k, endpoint=False)
    rings = []
    for t in np.linspace(0, 1, n):
        c = c_root + (c_tip - c_root) * t
        le = root + sd * span * t - [0, 0, span * t * np.tan(np.radians(sweep_deg))]
        zc = -c * (1 - np.cos(th)) / 2
        yc = thick * c * np.sin(th) * (0.6 + 0.4 * np.cos(th))
        rings.append(le + zc[:, None] * [0, 0, 1] + yc[:, None] * nrm)
    return loft(np.array(rings))


def airplane(rng: np.random.Generator) -> Assembly:
    """Airplane: fuselage, swept wings, tail (conventional/T/twin/V), 0/2/4 engines or a propeller."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["airliner", "fighter", "prop", "glider"], p=[0.4, 0.25, 0.2, 0.15])
    L = 1.0
    R = {"airliner": u(0.04, 0.07), "fighter": u(0.035, 0.06), "prop": u(0.035, 0.06), "glider": u(0.025, 0.04)}[kind]
    zs = np.linspace(-L / 2, L / 2, 18)
    t = (zs + L / 2) / L
    nose = u(0.08, 0.2)
    tail = u(0.25, 0.4)
    r = np.full_like(zs, R)
    tn = (L / 2 - zs) / nose
    r = np.where(tn < 1, R * np.sqrt(np.clip(1 - (1 - tn) ** 2, 0.02, 1)), r)
    tt = t / tail
    r = np.where(tt < 1, R * (0.25 + 0.75 * tt ** 0.8), r)
    yc = np.where(tt < 1, R * 0.6 * (1 - tt), 0.0)
    path = np.c_[np.zeros_like(zs), yc, zs]
    prof = np.array([ri * circle(12) * [1.0, u(1.0, 1.2)] for ri in r])
    a.add(sweep(path, prof))
    # Main wings.
    span = {"airliner": u(0.35, 0.55), "fighter": u(0.2, 0.32), "prop": u(0.4, 0.6), "glider": u(0.7, 1.1)}[kind]
    sw = {"airliner": u(15, 35), "fighter": u(35, 60), "prop": u(-3, 8), "glider": u(-2, 5)}[kind]
    cr = {"airliner": u(0.15, 0.25), "fighter": u(0.3, 0.45), "prop": u(0.12, 0.2), "glider": u(0.07, 0.11)}[kind]
    ct = cr * (u(0.05, 0.25) if kind == "fighter" else u(0.3, 0.8))
    dih = np.radians(u(-3, 8))
    wy = {"low": -0.6, "mid": 0.0, "high": 0.7}[rng.choice(["low", "mid", "high"])] * R
    wz = u(0.0, 0.18) if kind != "fighter" else u(-0.05, 0.1)
    sdir = [np.cos(dih), np.sin(dih), 0]
    a.add(wing([R * 0.5, wy, wz + cr / 2], sdir, span, cr, ct, sw, u(0.06, 0.12)), mirror_x=True)
    # Tail.
    tail_kind = rng.choice(["conventional", "t", "twin", "v"], p=[0.5, 0.2, 0.15, 0.15])
    if kind == "fighter" and rng.random() < 0.6:
        tail_kind = "twin"
    fin_h = u(0.1, 0.2)
    fin_c = u(0.1, 0.18)
    zt = -L / 2 + fin_c + 0.02
    ytop = R * 0.6
    if tail_kind in ("conventional", "t"):
        a.add(wing([0, ytop * 0.5, zt], [0, 1, 0], fin_h, fin_c, fin_c * 0.5, u(25, 50), 0.1))
        hy = ytop if tail_kind == "conventional" else ytop * 0.5 + fin_h
        hz = zt if tail_kind == "conventional" else zt - fin_h * np.tan(np.radians(35))
        a.add(wing([0.01, hy, hz], [1, 0.05, 0], u(0.1, 0.2), fin_c * 0.8, fin_c * 0.4, u(10, 35), 0.08),
              mirror_x=True)
    elif tail_kind == "twin":
        a.add(wing([R * 0.6, ytop * 0.5, zt], [0.25, 1, 0], fin_h, fin_c, fin_c * 0.5, u(30, 50), 0.08),
              mirror_x=True)
        a.add(wing([0.01, 0, zt], [1, 0, 0], u(0.1, 0.18), fin_c, fin_c * 0.4, u(20, 45), 0.08), mirror_x=True)
    else:
        a.add(wing([0.01, ytop * 0.5, zt], [1, 0.8, 0], u(0.12, 0.2), fin_c, fin_c * 0.5, u(20, 40), 0.08),
              mirror_x=True)
    # Engines.
    if kind == "airliner":
        n_eng = int(rng.choice([2, 2, 4, 0]))
        er = u(0.025, 0.045)
        el = u(0.1, 0.16)
        if n_eng == 0:
            for sx in (-1, 1):
                a.add(frustum([sx * (R + er), R * 0.3, -0.2], [sx * (R + er), R * 0.3, -0.2 + el], er * 0.8, er, k=12))
        for i in range(n_eng // 2):
            s = span * (0.35 + 0.3 * i)
            x = R * 0.5 + s * np.cos(dih)
            y = wy + s * np.sin(dih) - er * 1.3
            z = wz + cr / 2 - s * np.tan(np.radians(sw)) + el * 0.4
            a.add(frustum([x, y, z - el], [x, y, z], er * 0.75, er, k=12), mirror_x=True)
            a.add(box([x, y + er, z - el * 0.5], [0.008, er, el * 0.6]), mirror_x=True)
    elif kind == "prop":
        a.add(frustum([0, 0, L / 2 - 0.01], [0, 0, L / 2 + 0.04], R * 0.5, 0.005, k=10))
        nb = int(rng.integers(2, 5))
        pr = u(0.1, 0.18)
        for i in range(nb):
            ang = 2 * np.pi * i / nb
            a.add(box([pr / 2 * np.cos(ang), pr / 2 * np.sin(ang), L / 2 + 0.01], [pr, 0.02, 0.006],
                      np.array([[np.cos(ang), -np.sin(ang), 0], [np.sin(ang), np.cos(ang), 0], [0, 0, 1]])))
    elif kind == "fighter" and rng.random() < 0.5:
        a.add(ellipsoid([0, R * 0.8, L / 2 - nose - 0.05], [R * 0.6, R * 0.6, 0.1], k=10, s=6))
    return a


def car(rng: np.random.Generator) -> Assembly:
    """Car: lofted lower body, cabin (sedan/hatch/SUV/pickup/sports/van), four wheels, optional spoiler."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["sedan", "hatch", "suv", "pickup", "sports", "van"])
    L = 1.0
    W = u(0.36, 0.46)
    wr = u(0.075, 0.11)
    yb = wr * u(0.35, 0.6)
    belt = yb + {"sports": u(0.1, 0.13), "suv": u(0.17, 0.22), "van": u(0.17, 0.22), "pickup": u(0.16, 0.2)}.get(
        kind, u(0.13, 0.17))
    hood = belt - u(0.0, 0.03)
    zs = np.linspace(-L / 2, L / 2, 14)
    rings = []
    for z in zs:
        tz = abs(z) / (L / 2)
        top = hood if z > 0 else belt
        top = yb + (top - yb) * np.sqrt(max(1 - max(tz - 0.85, 0) / 0.15 * 0.5, 0.3))
        w = W * (1 - 0.15 * max(tz - 0.7, 0) / 0.3)
        prof = rounded_rect(w, top - yb, 0.03)
        rings.append(np.c_[prof[:, 0], prof[:, 1] + (top + yb) / 2, np.full(len(prof), z)])
    a.add(loft(np.array(rings)))
    roof = belt + {"sports": u(0.07, 0.1), "suv": u(0.14, 0.2), "van": u(0.16, 0.22)}.get(kind, u(0.11, 0.15))
    zf = {"van": u(0.3, 0.42), "sports": u(0.05, 0.15)}.get(kind, u(0.12, 0.25))
    ws = {"van": u(0.05, 0.12), "sports": u(0.15, 0.25)}.get(kind, u(0.12, 0.2))
    zr = {"sedan": u(-0.28, -0.18), "hatch": -0.45, "suv": -0.46, "pickup": u(-0.1, -0.02),
          "sports": u(-0.3, -0.2), "van": -0.47}[kind]
    rw = {"sedan": u(0.1, 0.18), "sports": u(0.15, 0.25), "hatch": u(0.05, 0.12)}.get(kind, u(0.01, 0.04))
    stations = [(zf, 0.005), (zf - ws, roof - belt), (zr + rw, roof - belt), (zr, 0.005)]
    cw = W * u(0.8, 0.92)
    crings = []
    for z, hh in stations:
        prof = np.array([[cw / 2, 0], [cw / 2 * 0.82, hh], [-cw / 2 * 0.82, hh], [-cw / 2, 0]])
        crings.append(np.c_[prof[:, 0], prof[:, 1] + belt - 0.002, np.full(4, z)])
    a.add(loft(np.array(crings)))
    if kind == "pickup":
        bed_len = zr + L / 2 - 0.02
        for sx in (-1, 1):
            a.add(box([sx * (W / 2 - 0.01), belt + 0.03, zr - bed_len / 2], [0.02, 0.06, bed_len]))
        a.add(box([0, belt + 0.03, -L / 2 + 0.01], [W, 0.06, 0.02]))
    wb = u(0.55, 0.68) * L
    ww = u(0.05, 0.08)
    for z in (wb / 2 + u(-0.03, 0.03), -wb / 2):
        for sx in (-1, 1):
            x = sx * (W / 2 - ww / 2 + 0.01)
            a.add(frustum([x - ww / 2, wr, z], [x + ww / 2, wr, z], wr, k=16))
    if kind in ("sports", "sedan") and rng.random() < 0.35:
        a.add(box([0, belt + 0.04, -L / 2 + 0.04], [W * 0.9, 0.01, 0.06]))
        a.add(box([W * 0.3, belt + 0.02, -L / 2 + 0.04], [0.01, 0.04, 0.03]), mirror_x=True)
    if kind in ("suv", "van") and rng.random() < 0.4:
        a.add(box([cw * 0.35, roof + 0.015, -0.05], [0.015, 0.015, 0.5]), mirror_x=True)
    return a


def watercraft(rng: np.random.Generator) -> Assembly:
    """Watercraft: lofted hull plus sails, cabins/superstructure and funnels, or a submarine/canoe."""
    a = Assembly()
    u = rng.uniform
    kind = rng.choice(["sail", "motor", "ship", "canoe", "sub"], p=[0.25, 0.25, 0.25, 0.12, 0.13])
    L = 1.0
    if kind == "sub":
        zs = np.linspace(-L / 2, L / 2, 16)
        R = u(0.05, 0.09)
        tt = (zs + L / 2) / L
        r = R * np.clip(np.sqrt(np.clip(1 - ((tt - 0.45) / 0.55) ** 4, 0, 1)), 0.05, 1)
        a.add(sweep(np.c_[np.zeros(16), np.zeros(16), zs], np.array([ri * circle(12) for ri in r])))
        tz = u(0.0, 0.2)
        a.add(box([0, R + u(0.04, 0.08) / 2, tz], [R * 0.5, u(0.06, 0.12), u(0.08, 0.14)]))
        a.add(wing([0.01, 0, -L / 2 + 0.1], [1, 0, 0], R * 1.5, 0.08, 0.05, 20, 0.1), mirror_x=True)
        a.add(wing([0, 0.01, -L / 2 + 0.1], [0, 1, 0], R * 1.5, 0.08, 0.05, 20, 0.1))
        return a
    W = {"canoe": u(0.1, 0.16), "ship": u(0.1, 0.17)}.get(kind, u(0.2, 0.38))
    D = u(0.06, 0.12) if kind != "ship" else u(0.08, 0.13)
    vee = u(0.5, 1.5)
    zs = np.linspace(-L / 2, L / 2, 16)
    rings = []
    th = np.linspace(0, np.pi, 11)
    for z in zs:
        t = (z + L / 2) / L
        if kind == "canoe":
            w = W * np.sqrt(max(1 - (2 * t - 1) ** 2, 0.02))
        else:
            w = W * (np.sqrt(max(1 - ((t - 0.35) / 0.65) ** 2, 0.02)) if t > 0.35 else 1 - 0.15 * (0.35 - t))
        sheer = D * 0.4 * max(t - 0.6, 0) / 0.4
        depth = D * (1 - 0.5 * max(t - 0.75, 0) / 0.25)
        x = w / 2 * np.cos(th)
        y = -depth * np.sin(th) ** vee + sheer
        rings.append(np.c_[x, y, np.full_like(x, z)])
    a.add(loft(np.array(rings)))
    if kind == "sail":
        mz = u(0.0, 0.2)
        mh = u(0.6, 1.1)
        a.add(frustum([0, 0, mz], [0, mh, mz], 0.01, 0.006, k=8))
        boom = u(0.25, 0.45)
        tri = np.array([[0, 0.05, mz - 0.01], [0, mh * 0.95, mz - 0.01], [0, 0.05, mz - boom]])
        v = np.r_[tri + [0.004, 0, 0], tri - [0.004, 0, 0]]
        a.add((v, np.array([[0, 1, 2], [3, 5, 4], [0, 3, 4], [0, 4, 1], [1, 4, 5], [1, 5, 2], [2, 5, 3], [2, 3, 0]])))
        if rng.random() < 0.6:
            jib = np.array([[0, 0.04, mz + 0.01], [0, mh * 0.8, mz + 0.01], [0, 0.04, L / 2 - 0.05]])
            v = np.r_[jib + [0.004, 0, 0], jib - [0.004, 0, 0]]
            a.add((v, np.array([[0, 1, 2], [3, 5, 4], [0, 3, 4], [0, 4, 1], [1, 4, 5], [1, 5, 2], [2, 5, 3],
                                [2, 3, 0]])))
        a.add(box([0, -D - 0.06, mz - 0.05], [0.015, 0.14, u(0.08, 0.16)]))
        if rng.random() < 0.5:
            a.add(box([0, 0.03, -0.1], [W * 0.5, 0.05, 0.2]))
    elif kind == "motor":
        n = int(rng.integers(1, 3))
        ch = u(0.05, 0.09)
        for i in range(n):
            cl = u(0.25, 0.4) * (0.7 ** i)
            a.add(box([0, ch * (i + 0.5), -0.1 + 0.03 * i], [W * (0.6 - 0.12 * i), ch, cl]))
        a.add(box([0, ch * n + 0.02, -0.05], [W * 0.4, 0.04, 0.01], rot_x(-30)))
    elif kind == "ship":
        n = int(rng.integers(1, 4))
        z0 = u(-0.3, -0.1)
        for i in range(n):
            a.add(box([0, 0.03 + 0.04 * i, z0 + 0.02 * i], [W * (0.8 - 0.15 * i), 0.04, u(0.12, 0.3) * (0.8 ** i)]))
        top = 0.05 + 0.04 * n
        for j in range(int(rng.integers(0, 3))):
            fz = z0 - 0.05 - 0.08 * j
            a.add(frustum([0, top - 0.04, fz], [0, top + u(0.04, 0.1), fz], u(0.015, 0.03), k=10))
        a.add(frustum([0, top, z0 + 0.05], [0, top + u(0.08, 0.2), z0 + 0.05], 0.005, k=6))
        if rng.random() < 0.5:
            for z in (u(0.15, 0.3), u(-0.4, -0.35)):
                a.add(frustum([0, 0.0, z], [0, 0.04, z], 0.03, k=10))
                a.add(frustum([0, 0.03, z], [0, 0.03, z + 0.08], 0.006, k=6))
    else:
        for z in (-0.2, 0.2):
            a.add(box([0, -D * 0.3, z], [W * 0.7, 0.01, 0.04]))
    return a


def rifle(rng: np.random.Generator) -> Assembly:
    """Rifle: stock, receiver, barrel, handguard, grip, trigger guard, optional magazine/scope/bipod."""
    a = Assembly()
    u = rng.uniform
    L = 1.0
    rh = u(0.05, 0.08)
    rw = u(0.025, 0.04)
    stock_l = u(0.22, 0.32)
    rec_l = u(0.15, 0.28)
    z0 = -L / 2
    sz = np.array([z0, z0 + stock_l])
    drop = u(0.0, 0.05)
    if rng.random() < 0.2:
        a.add(tube(np.array([[0, rh * 0.4, z0 + 0.01], [0, rh * 0.4, z0 + stock_l + 0.02]]), 0.008, k=6))
        a.add(box([0, rh * 0.1 - drop / 2, z0 + 0.01], [rw * 0.8, rh * 1.4, 0.02]))
        a.add(tube(np.array([[0, -rh * 0.5 - drop, z0 + 0.01], [0, -0.2 * rh, z0 + stock_l]]), 0.008, k=6))
    else:
        rings = []
        for z, hh, yy in ((sz[0], rh * u(1.4, 2.0), -drop - rh * 0.2), (sz[1], rh * 0.7, 0.0)):
            prof = rounded_rect(rw, hh, 0.01)
            rings.append(np.c_[prof[:, 0], prof[:, 1] + yy, np.full(len(prof), z)])
        a.add(loft(np.array(rings)))
    zr = z0 + stock_l
    a.add(box([0, 0, zr + rec_l / 2], [rw, rh, rec_l]))
    bl = L - stock_l - rec_l
    br = u(0.008, 0.014)
    a.add(frustum([0, rh * 0.2, zr + rec_l], [0, rh * 0.2, L / 2], br * 1.2, br, k=10))
    hg = bl * u(0.3, 0.7)
    if rng.random() < 0.8:
        a.add(frustum([0, rh * 0.1, zr + rec_l - 0.01], [0, rh * 0.1, zr + rec_l + hg], rh * 0.45, rh * 0.38, k=10))
    gz = zr + u(0.0, 0.05)
    a.add(box([0, -rh * 0.9, gz], [rw * 0.8, rh * 1.2, 0.035], rot_x(u(-30, -10))))
    guard = np.array([[0, -rh / 2, gz + 0.02], [0, -rh * 1.0, gz + 0.03], [0, -rh * 1.0, gz + 0.08],
                      [0, -rh / 2, gz + 0.09]])
    a.add(tube(guard, 0.004, k=6))
    if rng.random() < 0.7:
        ml = u(0.08, 0.18)
        mz = zr + rec_l * 0.6
        bend = u(0, 25)
        a.add(box([0, -rh / 2 - ml / 2, mz], [rw * 0.7, ml, 0.05], rot_x(bend)))
    if rng.random() < 0.45:
        sl = u(0.18, 0.3)
        sr = u(0.01, 0.018)
        y = rh / 2 + u(0.03, 0.05)
        zc = zr + rec_l / 2
        a.add(frustum([0, y, zc - sl / 2], [0, y, zc + sl / 2], sr, sr, k=10))
        a.add(frustum([0, y, zc - sl / 2 - 0.04], [0, y, zc - sl / 2], sr * 1.5, sr, k=10))
        a.add(frustum([0, y, zc + sl / 2], [0, y, zc + sl / 2 + 0.05], sr, sr * 1.8, k=10))
        for dz in (-0.04, 0.04):
            a.add(box([0, (rh / 2 + y) / 2, zc + dz], [0.01, y - rh / 2, 0.015]))
    if rng.random() < 0.25:
        bz = L / 2 - bl * 0.4
        for sx in (-1, 1):
            a.add(tube(np.array([[0, 0, bz], [sx * 0.05, -0.2, bz + 0.03]]), 0.005, k=6))
    if rng.random() < 0.4:
        a.add(frustum([0, rh * 0.2, L / 2], [0, rh * 0.2, L / 2 + 0.04], br * 2, br * 2, k=10))
    return a


__all__ = ["airplane", "car", "rifle", "watercraft", "wing"]
