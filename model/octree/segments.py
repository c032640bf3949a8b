"""Runs of consecutive items: the index ranges of runs and per-run sums, without Python loops.

Points sorted by Morton key form one run per octant, so the build sums moments and gathers an
octant's points through these two functions.
"""

from __future__ import annotations

import numpy as np


def concat_ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for all pairs, without a Python loop."""
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    offs = np.cumsum(count) - count
    return np.repeat(start - offs, count) + np.arange(total)


def segment_sums(rows: np.ndarray, new: np.ndarray, n: int) -> np.ndarray:
    """Sums (R, n) of each row over consecutive segments (``new`` marks each segment's start),
    equal bit for bit to ``np.add.reduceat(rows, starts, axis=1)`` and faster on short segments.

    reduceat adds a segment as ``x0 + (((0 + x1) + x2) + ...)`` when it has at most 8 elements
    (longer ones are summed pairwise); ``bincount`` adds in order from 0, so the heads plus the
    bincount of the tails give the same numbers.  Segments over 8 elements use reduceat itself.
    The equality keeps planes, and with them every label and patch error, unchanged by this
    speed-up: the patch error is not continuous in the plane where a polygon is degenerate.
    """
    starts = np.flatnonzero(new)
    count = np.diff(np.r_[starts, rows.shape[1]])
    long_ = np.flatnonzero(count > 8)
    if count[long_].sum() * 2 > rows.shape[1]:      # mostly long segments (dense voxels)
        return np.add.reduceat(rows, starts, axis=1)
    tail = np.flatnonzero(~new)
    st = (np.cumsum(new) - 1)[tail]
    out = np.take(rows, starts, axis=1)
    for r, row in enumerate(rows):           # row by row: no second copy of all rows
        out[r] += np.bincount(st, weights=row[tail], minlength=n)
    if len(long_):
        idx = concat_ranges(starts[long_], count[long_])
        out[:, long_] = np.add.reduceat(np.take(rows, idx, axis=1),
                                        np.cumsum(count[long_]) - count[long_], axis=1)
    return out
