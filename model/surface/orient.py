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
from scipy.sparse.csgraph import breadth_first_order, connected_components, minimum_spanning_tree

from .grid import Leaves

PARALLEL = 0.7
"""|cos| of the angle between two planes above which they can continue one another."""
CLOSE = 0.35
"""How far (in finest cells) each plane may pass from the other's patch centre."""


def adjacent_pairs(owner: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Leaf pairs (P, 2), lower first, whose cells touch across a face, and how many cell faces
    they share."""
    span = np.int64(max(int(owner.max()) + 1, 1))
    keys = []
    for axis in range(3):
        a = np.moveaxis(owner, axis, 0)
        x, y = a[:-1].ravel(), a[1:].ravel()
        keep = (x >= 0) & (y >= 0) & (x != y)
        x, y = x[keep].astype(np.int64), y[keep].astype(np.int64)
        keys.append(np.minimum(x, y) * span + np.maximum(x, y))
    unique, count = np.unique(np.concatenate(keys), return_counts=True)
    return np.stack([unique // span, unique % span], 1), count


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
    # a spanning tree of the links (largest contacts first); each group rooted at its largest leaf
    tree = minimum_spanning_tree(coo_matrix((1.0 / weight, (a, b)), shape=(count, count)).tocsr())
    tree = tree + tree.T
    groups, label = connected_components(tree, directed=False)
    area = leaves.cells.astype(np.float64) ** 2
    by_group = np.lexsort((-area, label))
    roots = by_group[np.r_[True, label[by_group][1:] != label[by_group][:-1]]]
    # one breadth-first search from a virtual node joined to every root
    forest = coo_matrix((np.r_[tree.tocoo().data, np.ones(groups)],
                         (np.r_[tree.tocoo().row, np.full(groups, count)], np.r_[tree.tocoo().col, roots])),
                        shape=(count + 1, count + 1)).tocsr()
    _, pred = breadth_first_order(forest, count, directed=False)
    parent = np.where(pred[:count] >= 0, pred[:count], np.arange(count))
    parent[roots] = roots
    sign = coo_matrix((np.where(agree, 1.0, -1.0), (a, b)), shape=(count, count)).tocsr()
    sign = sign + sign.T
    nonroot = parent != np.arange(count)
    step = np.ones(count)
    step[nonroot] = np.asarray(sign[parent[nonroot], np.flatnonzero(nonroot)]).ravel()
    # each leaf's parity relative to its root: the product of the steps on its way up, by pointer jumping
    parity, up = step, parent
    while np.any(up[up] != up):                   # invariant: parity = product of the steps from a leaf to up
        parity, up = parity * parity[up], up[up]
    pos = np.bincount(label, area * (parity > 0), groups)
    neg = np.bincount(label, area * (parity < 0), groups)
    size = np.bincount(label, minlength=groups)
    keep = pos[label] >= neg[label]
    flip = (size[label] >= 2) & np.where(keep, parity < 0, parity > 0)
    if not flip.any():
        return leaves, 0
    s = np.where(flip, -1.0, 1.0)
    return dataclasses.replace(leaves, normal=leaves.normal * s[:, None], const=leaves.const * s), int(flip.sum())
