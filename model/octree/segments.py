"""Runs of consecutive items: the index ranges of runs and per-run sums, without Python loops.

Points sorted by Morton key form one run per octant, so the build sums moments and gathers an
octant's points through these two functions.
"""

from __future__ import annotations

import numpy as np

from .jit import compiled


def concat_ranges(start: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Concatenation of ``arange(s, s + c)`` for all pairs, without a Python loop."""
    total = int(count.sum())
    if total == 0:
        return np.zeros(0, dtype=np.int64)
    offs = np.cumsum(count) - count
    return np.repeat(start - offs, count) + np.arange(total)


def segment_sums(rows: np.ndarray, new: np.ndarray, n: int) -> np.ndarray:
    """Sums (R, n) of each row over consecutive segments (``new`` marks each segment's start),
    equal bit for bit to ``np.add.reduceat(rows, starts, axis=1)``, compiled.

    reduceat adds a segment as its first element plus NumPy's pairwise sum of the rest
    (:func:`_pairwise`).  The equality keeps planes, and with them every label and patch error,
    unchanged by this speed-up: the patch error is not continuous in the plane where a polygon is
    degenerate.
    """
    starts = np.flatnonzero(new)
    if len(starts) != n:
        raise ValueError(f"new marks {len(starts)} segments, expected {n}")
    out = np.empty((rows.shape[0], n))
    _segment_sums(np.ascontiguousarray(rows, dtype=np.float64), starts, out)
    return out


@compiled
def _segment_sums(rows: np.ndarray, starts: np.ndarray, out: np.ndarray) -> None:
    """Row by row, segment by segment (segment ``j`` from ``starts[j]`` to the next start)."""
    width = rows.shape[1]
    for r in range(rows.shape[0]):
        row = rows[r]
        for j in range(len(starts)):
            a = starts[j]
            b = starts[j + 1] if j + 1 < len(starts) else width
            if b - a <= 8:                      # the short runs of most octants: one by one
                total = -0.0                    # NumPy's start: x + -0.0 is x, a -0.0 kept
                for i in range(a + 1, b):
                    total += row[i]
                out[r, j] = row[a] + total
            else:
                out[r, j] = row[a] + _pairwise(row, a + 1, b - a - 1)


@compiled
def _pairwise(x: np.ndarray, first: int, n: int) -> float:
    """NumPy's pairwise sum of ``x[first:first + n]`` (what a contiguous add-reduction adds to its
    first element): below 8 values one by one from 0; up to 128, eight running sums combined as a
    tree, then the rest one by one; above, the two halves (the first a multiple of 8) summed so.
    Zeros keep their sign as NumPy's do (its running sum starts at -0.0)."""
    if n < 8:
        total = -0.0
        for i in range(first, first + n):
            total += x[i]
        return total
    if n > 128:
        half = n // 2
        half -= half % 8
        return _pairwise(x, first, half) + _pairwise(x, first + half, n - half)
    r0, r1, r2, r3 = x[first], x[first + 1], x[first + 2], x[first + 3]
    r4, r5, r6, r7 = x[first + 4], x[first + 5], x[first + 6], x[first + 7]
    i = 8
    while i < n - n % 8:
        r0 += x[first + i]
        r1 += x[first + i + 1]
        r2 += x[first + i + 2]
        r3 += x[first + i + 3]
        r4 += x[first + i + 4]
        r5 += x[first + i + 5]
        r6 += x[first + i + 6]
        r7 += x[first + i + 7]
        i += 8
    total = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        total += x[first + i]
        i += 1
    return total
