"""Consistent orientation of the leaf planes that continue one another.

A leaf's plane says which side is inside.  Where a part is thinner than a cell, one plane stands
for both of its faces and its normal is a guess (the two faces' normals cancel), so neighbouring
leaves along the part point either way; a decoder's mistakes flip single planes too.  Where the
inside then changes sides from one leaf to the next, the closed surface would get holes.

Two face-adjacent leaves *continue* one another when each one's plane passes close to the other
one's patch and the planes are near parallel or anti-parallel.  Along these links the planes
are made to agree: a spanning tree of each connected group propagates one orientation, and the
group keeps the orientation most of its patch area had (so a decoder's isolated flip is undone,
and a well-oriented solid is left as it was).  Links between leaves whose planes are apart (the
two faces of a part at least a cell thick, back to back) impose nothing.
"""

from __future__ import annotations

import dataclasses

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import breadth_first_order, connected_components

from .grid import Leaves

PARALLEL = 0.7
"""|cos| of the angle between two planes above which they can continue one another."""
CLOSE = 0.35
"""How far (in finest cells) each plane may pass from the other's patch centre."""


def adjacent_pairs(owner: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Leaf pairs (P, 2), lower first, whose cells touch across a face, and how many cell faces
    they share."""
    pairs = []
    for axis in range(3):
        a = np.moveaxis(owner, axis, 0)
        x, y = a[:-1].ravel(), a[1:].ravel()
        keep = (x >= 0) & (y >= 0) & (x != y)
        pairs.append(np.stack([np.minimum(x[keep], y[keep]), np.maximum(x[keep], y[keep])], 1))
    pairs = np.concatenate(pairs)
    if not len(pairs):
        return np.zeros((0, 2), np.int64), np.zeros(0, np.int64)
    unique, count = np.unique(pairs, axis=0, return_counts=True)
    return unique.astype(np.int64), count


def patch_centres(leaves: Leaves, h: float) -> np.ndarray:
    """The point of each leaf's plane nearest its cube's centre (cube coordinates)."""
    centre = (leaves.origin + leaves.cells[:, None] / 2.0) * h
    dist = np.einsum("ij,ij->i", centre, leaves.normal) + leaves.const
    return centre - dist[:, None] * leaves.normal


def orient(leaves: Leaves, owner: np.ndarray, h: float) -> tuple[Leaves, int]:
    """``leaves`` with the planes that continue one another oriented alike (module docstring), and
    how many planes were flipped."""
    pairs, contact = adjacent_pairs(owner)
    if not len(pairs):
        return leaves, 0
    a, b = pairs.T
    n, c = leaves.normal, leaves.const
    dot = np.einsum("ij,ij->i", n[a], n[b])
    p = patch_centres(leaves, h)
    close = (np.abs(np.einsum("ij,ij->i", p[b], n[a]) + c[a]) <= CLOSE * h) & \
            (np.abs(np.einsum("ij,ij->i", p[a], n[b]) + c[b]) <= CLOSE * h)
    link = close & (np.abs(dot) >= PARALLEL)
    if not link.any():
        return leaves, 0
    a, b, agree, weight = a[link], b[link], dot[link] > 0, contact[link]
    count = len(leaves)
    # a spanning tree of the links (largest contacts first), then parities from each root down it
    graph = coo_matrix((1.0 / weight, (a, b)), shape=(count, count)).tocsr()
    from scipy.sparse.csgraph import minimum_spanning_tree

    tree = minimum_spanning_tree(graph)
    tree = tree + tree.T
    sign = coo_matrix((np.where(agree, 1, -1), (a, b)), shape=(count, count)).tocsr()
    sign = sign + sign.T
    groups, label = connected_components(tree, directed=False)
    parity = np.ones(count, np.int64)
    area = (leaves.cells.astype(np.float64)) ** 2
    flip = np.zeros(count, bool)
    for g in range(groups):
        members = np.flatnonzero(label == g)
        if len(members) < 2:
            continue
        root = members[np.argmax(area[members])]
        order, pred = breadth_first_order(tree, root, directed=False)
        for node in order[1:]:
            parity[node] = parity[pred[node]] * sign[pred[node], node]
        keep = area[members][parity[members] > 0].sum() >= area[members][parity[members] < 0].sum()
        flip[members] = (parity[members] < 0) if keep else (parity[members] > 0)
    if not flip.any():
        return leaves, 0
    s = np.where(flip, -1.0, 1.0)
    return dataclasses.replace(leaves, normal=leaves.normal * s[:, None], const=leaves.const * s), int(flip.sum())
