"""Dual marching cubes case tables: for each of the 256 inside/outside configurations of a cell's
corners, its surface components and which corner belongs to which.

Corner ``c`` of a cell is ``(c & 1, c >> 1 & 1, c >> 2 & 1)`` (x, y, z offsets); bit ``c`` of a
configuration is set when that corner is inside.  Inside corners are connected along the cell's
edges only (6-connectivity), so on a face whose two inside corners are diagonal the two are
separated, the same way from both cells that share the face: the rule that makes the dual mesh
of neighbouring cells agree.  Each connected group of inside corners is bounded by one surface
component in the cell, which becomes one vertex of the dual mesh.  Two kinds of configuration
would break the mesh's manifoldness and are repaired before meshing
(:func:`model.surface.dmc.repair`), by turning one outside corner inside: a component that
is not a disk (an annulus: the surface tunnels through the cell), and a component that meets a
face in two pieces (the face's inside corners are diagonal but connected through the cell).
Without them every vertex's quads close around it in one fan and two cells share at most one
dual edge per face: the dual mesh is a closed 2-manifold.
"""

from __future__ import annotations

import numpy as np

CORNERS = np.array([[c & 1, c >> 1 & 1, c >> 2 & 1] for c in range(8)])
"""(8, 3) corner offsets."""
EDGES = np.array([(a, b) for a in range(8) for b in range(a + 1, 8)
                  if np.abs(CORNERS[a] - CORNERS[b]).sum() == 1])
"""(12, 2) corner pairs along the cell's edges (the lower corner first)."""
FACES = np.array([[c for c in range(8) if CORNERS[c][axis] == side] for axis in range(3) for side in (0, 1)])
"""(6, 4) corners of each face."""


def _face_cycle(face: np.ndarray) -> list[int]:
    """The face's 4 corners in cyclic order (consecutive ones share an edge)."""
    a = int(face[0])
    ring = [a]
    while len(ring) < 4:
        nxt = next(int(c) for c in face if c not in ring and np.abs(CORNERS[c] - CORNERS[ring[-1]]).sum() == 1)
        ring.append(nxt)
    return ring


FACE_CYCLES = [_face_cycle(f) for f in FACES]
EDGE_INDEX = {(int(a), int(b)): i for i, (a, b) in enumerate(EDGES)} | {(int(b), int(a)): i for i, (a, b) in enumerate(EDGES)}


def components(config: int) -> list[list[int]]:
    """The inside corners of ``config`` grouped by connectivity along the cell's edges."""
    inside = [c for c in range(8) if config >> c & 1]
    groups: list[list[int]] = []
    seen: set[int] = set()
    for c in inside:
        if c in seen:
            continue
        stack, group = [c], []
        seen.add(c)
        while stack:
            x = stack.pop()
            group.append(x)
            for y in inside:
                if y not in seen and np.abs(CORNERS[x] - CORNERS[y]).sum() == 1:
                    seen.add(y)
                    stack.append(y)
        groups.append(sorted(group))
    return groups


def boundary_loops(config: int, group: list[int]) -> int:
    """How many loops bound the surface component around ``group`` on the cell's faces."""
    crossed = {EDGE_INDEX[(a, b)] for a in group for b in range(8) if not config >> b & 1
               and np.abs(CORNERS[a] - CORNERS[b]).sum() == 1}
    links: dict[int, list[int]] = {e: [] for e in crossed}
    for ring in FACE_CYCLES:
        inside = [config >> c & 1 for c in ring]
        if all(inside) or not any(inside):
            continue
        k = 0
        while inside[k] or not inside[(k + 1) % 4]:          # k: an outside corner followed by an inside one
            k += 1
        ring = ring[k + 1:] + ring[:k + 1]                      # now starts with an inside corner
        inside = [config >> c & 1 for c in ring]
        i = 0
        while i < 4:                                            # runs of consecutive inside corners
            if not inside[i]:
                i += 1
                continue
            j = i
            while j + 1 < 4 and inside[j + 1]:
                j += 1
            if ring[i] in group:
                first = EDGE_INDEX[(ring[i], ring[i - 1])]      # the side entering the run
                last = EDGE_INDEX[(ring[j], ring[(j + 1) % 4])]
                links[first].append(last)
                links[last].append(first)
            i = j + 1
    loops, seen = 0, set()
    for e in links:
        if e in seen:
            continue
        loops += 1
        stack = [e]
        while stack:
            x = stack.pop()
            if x in seen:
                continue
            seen.add(x)
            stack.extend(links[x])
    return loops


def repair_corner(config: int, corner_component: np.ndarray) -> int:
    """An outside corner to turn inside so that no component of ``config`` is an annulus or meets
    one face in two pieces (-1 when there is none to repair).  A face whose inside corners are
    diagonal, and connected through the rest of the cell, is crossed twice by one component: the
    cell across the face sees the same, and the two cells' vertices would be joined twice."""
    for ring in FACE_CYCLES:
        inside = [config >> c & 1 for c in ring]
        if inside in ([1, 0, 1, 0], [0, 1, 0, 1]):
            a, b = [c for c in ring if config >> c & 1]
            if corner_component[a] == corner_component[b]:
                return min(c for c in ring if not config >> c & 1)
    groups = components(config) if 0 < config < 255 else []
    if any(boundary_loops(config, g) != 1 for g in groups):
        return min(c for c in range(8) if not config >> c & 1)
    return -1


def _tables():
    count = np.zeros(256, np.int64)
    corner_component = np.full((256, 8), -1, np.int64)
    repair = np.full(256, -1, np.int64)
    for config in range(256):
        groups = components(config) if 0 < config < 255 else []
        count[config] = len(groups)
        for k, group in enumerate(groups):
            corner_component[config, group] = k
        repair[config] = repair_corner(config, corner_component[config])
    return count, corner_component, repair


COMPONENTS, CORNER_COMPONENT, REPAIR = _tables()
"""Per configuration: the number of surface components (vertices) of the cell; for each corner,
the component of its group (-1 for outside corners); the corner :func:`repair_corner` turns
inside (-1: the configuration needs no repair)."""
