"""Morton (shuffled) keys of octants, with the batch index in the high bits.

A key at depth ``l`` interleaves the ``l``-bit integer coordinates as ``...x1y1z1 x0y0z0`` (x the
most significant of each triple), so sorting keys sorts octants depth-first and the 8 children of
an octant are the 8 consecutive keys ``parent << 3 | slot`` with ``slot = 4x + 2y + z``.
"""

from __future__ import annotations

import numpy as np

from .jit import compiled

MAX_DEPTH = 16
"""Coordinates use up to 16 bits per axis (48 bits of key)."""
BATCH_SHIFT = 48
"""The batch index occupies bits 48..63 (up to 65,536 shapes in one batch)."""
_MORTON_MASK = np.uint64((1 << BATCH_SHIFT) - 1)


SPREAD = ((16, 0x0000_FF00_00FF), (8, 0x00F0_0F00_F00F), (4, 0x0C30_C30C_30C3), (2, 0x2492_4924_9249))
"""The shifts and masks that insert two zero bits between each of the low 16 bits of a number."""


def _spread_bits(v: np.ndarray) -> np.ndarray:
    """Insert two zero bits between each of the low 16 bits of ``v`` (uint64)."""
    v = v.astype(np.uint64) & np.uint64(0xFFFF)
    for shift, mask in SPREAD:
        v = (v | (v << np.uint64(shift))) & np.uint64(mask)
    return v


@compiled
def cell_keys(cube: np.ndarray, res: int) -> np.ndarray:
    """The keys (batch 0) of the finest octants of points ``cube`` (N, 3) in the unit cube at ``res``
    octants a side: ``encode(clip((cube * res).astype(int64), 0, res - 1))``, point by point (the
    product truncated toward zero, as NumPy's cast does) in one compiled pass."""
    out = np.empty(len(cube), np.uint64)
    for i in range(len(cube)):
        key = np.uint64(0)
        for a in range(3):
            v = np.uint64(min(max(int(cube[i, a] * res), 0), res - 1))
            for shift, mask in SPREAD:
                v = (v | (v << np.uint64(shift))) & np.uint64(mask)
            key |= v << np.uint64(2 - a)
        out[i] = key
    return out


def _compact_bits(v: np.ndarray) -> np.ndarray:
    """Inverse of :func:`_spread_bits`: gather every third bit into the low 16 bits."""
    v = v & np.uint64(0x2492_4924_9249)
    v = (v | (v >> np.uint64(2))) & np.uint64(0x0C30_C30C_30C3)
    v = (v | (v >> np.uint64(4))) & np.uint64(0x00F0_0F00_F00F)
    v = (v | (v >> np.uint64(8))) & np.uint64(0x0000_FF00_00FF)
    v = (v | (v >> np.uint64(16))) & np.uint64(0xFFFF)
    return v


def encode(xyz: np.ndarray, batch: np.ndarray | int = 0) -> np.ndarray:
    """Keys (uint64) of integer octant coordinates ``xyz`` (N, 3) and batch indices."""
    xyz = np.asarray(xyz)
    if xyz.ndim != 2 or xyz.shape[1] != 3:
        raise ValueError(f"xyz must have shape (N, 3), got {xyz.shape}")
    if xyz.size and (xyz.min() < 0 or xyz.max() >= (1 << MAX_DEPTH)):
        raise ValueError(f"coordinates must lie in [0, 2**{MAX_DEPTH})")
    key = (_spread_bits(xyz[:, 0]) << np.uint64(2)) | (_spread_bits(xyz[:, 1]) << np.uint64(1))
    key |= _spread_bits(xyz[:, 2])
    b = np.asarray(batch, dtype=np.uint64)
    return key | (b << np.uint64(BATCH_SHIFT))


def decode(keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Integer coordinates (N, 3) int64 and batch indices (N,) int64 of ``keys``."""
    keys = np.asarray(keys, dtype=np.uint64)
    xyz = np.stack(
        [_compact_bits(keys >> np.uint64(s)) for s in (2, 1, 0)], axis=1
    ).astype(np.int64)
    return xyz, (keys >> np.uint64(BATCH_SHIFT)).astype(np.int64)


def batch_of(keys: np.ndarray) -> np.ndarray:
    """Batch index (int64) of each key."""
    return (np.asarray(keys, dtype=np.uint64) >> np.uint64(BATCH_SHIFT)).astype(np.int64)


def parent_keys(keys: np.ndarray, levels: int = 1) -> np.ndarray:
    """Keys of the ancestors ``levels`` depths up, batch bits kept."""
    keys = np.asarray(keys, dtype=np.uint64)
    batch = keys & ~_MORTON_MASK
    return batch | ((keys & _MORTON_MASK) >> np.uint64(3 * levels))


def child_keys(keys: np.ndarray) -> np.ndarray:
    """Keys (8N,) of the 8 children of each key, in slot order, batch bits kept."""
    keys = np.asarray(keys, dtype=np.uint64)
    batch = keys & ~_MORTON_MASK
    inner = (keys & _MORTON_MASK) << np.uint64(3)
    return ((batch | inner)[:, None] | np.arange(8, dtype=np.uint64)[None]).ravel()


def lookup(table: np.ndarray, query: np.ndarray) -> np.ndarray:
    """Row of each ``query`` key in the ascending ``table`` of keys (int64), ``len(table)`` where a
    key is absent (the row a padded table keeps for "not found").  Both may hold batch bits."""
    table = np.asarray(table, dtype=np.uint64)
    query = np.asarray(query, dtype=np.uint64)
    at = np.searchsorted(table, query).astype(np.int64)
    found = at < len(table)
    found[found] = table[at[found]] == query[found]
    return np.where(found, at, len(table))


def with_batch(keys: np.ndarray, batch: np.ndarray | int) -> np.ndarray:
    """``keys`` with their batch bits replaced by ``batch``."""
    keys = np.asarray(keys, dtype=np.uint64)
    return (keys & _MORTON_MASK) | (np.asarray(batch, dtype=np.uint64) << np.uint64(BATCH_SHIFT))
