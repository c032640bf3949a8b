"""Two builds of one dataset, compared record by record: how far their arrays differ.

The build is deterministic on one machine (a rebuild gives the same bytes).  On another machine
the octree structure and every integer array are the same, but floating values may differ in
their last bits: NumPy's vectorised maths and the BLAS kernels round differently on CPUs with
other SIMD extensions (measured between the AVX-512 and AVX2 code paths: 4 of 26 records
differ, by at most 3e-18 in a plane component, 1e-17 in a scan normal and 2e-12 in a patch
error), and a record's bytes, hence its sha256 and the manifest's, then differ too.  This says
whether two builds are the same dataset up to such rounding.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from .dataset import load_record


@dataclass
class ArrayDifference:
    """One array name over the records both builds hold: in how many it differs, and by how much."""

    records: int = 0
    max_abs: float = 0.0
    shape_or_integer: int = 0        # records where its shape or an integer/boolean value differs


@dataclass
class DatasetComparison:
    """``same_bytes`` records have equal sha256; ``arrays`` lists only arrays that differ somewhere."""

    compared: int
    same_bytes: int
    missing: list[str]
    arrays: dict[str, ArrayDifference] = field(default_factory=dict)

    @property
    def same_structure(self) -> bool:
        return not self.missing and all(d.shape_or_integer == 0 for d in self.arrays.values())


def compare_datasets(a: str | Path, b: str | Path) -> DatasetComparison:
    """Compare every record of dataset ``a`` with the record of the same path in ``b``."""
    a, b = Path(a), Path(b)
    rows_a = {r["path"]: r for r in json.loads((a / "manifest.json").read_text())["records"]}
    rows_b = {r["path"]: r for r in json.loads((b / "manifest.json").read_text())["records"]}
    common = sorted(set(rows_a) & set(rows_b))
    out = DatasetComparison(len(common), 0, sorted(set(rows_a) ^ set(rows_b)))
    for path in common:
        if rows_a[path]["sha256"] == rows_b[path]["sha256"]:
            out.same_bytes += 1
            continue
        ra, rb = load_record(a / path).arrays, load_record(b / path).arrays
        for name in sorted(set(ra) | set(rb)):
            x, y = ra.get(name), rb.get(name)
            floating = x is not None and x.dtype.kind == "f"
            if x is not None and y is not None and np.array_equal(x, y, equal_nan=floating):
                continue
            d = out.arrays.setdefault(name, ArrayDifference())
            d.records += 1
            if x is None or y is None or x.shape != y.shape or not floating:
                d.shape_or_integer += 1
            else:
                with np.errstate(invalid="ignore"):                   # inf - inf where both are infinite
                    d.max_abs = max(d.max_abs, float(np.nanmax(np.abs(x.astype(np.float64) - y))))
    return out
