"""Derived training data cached beside a dataset: one .npz per record, keyed by the record's
checksum and the settings that derived it, built in parallel on first use and rebuilt when stale.

Tasks whose inputs are expensive to derive from a record (completion's partial-scan octrees,
classification's rotated octrees) cache them here so reruns and resumed runs start in seconds.
"""

from __future__ import annotations

import hashlib
import io
import json
from pathlib import Path
from typing import Callable

import numpy as np

from ..data.dataset import ShapeRecord, load_record
from ..files import write_atomic
from .data import process_map


def cache_dir(data_dir: str | Path, name: str, settings: dict) -> Path:
    """``<data>/cache/<name>-<fingerprint of settings>``."""
    key = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:12]
    return Path(data_dir) / "cache" / f"{name}-{key}"


def cached_arrays(path: Path, sha: str, build: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays cached at ``path`` for the record of checksum ``sha``, built and written
    atomically when missing, stale or unreadable."""
    if path.is_file():
        try:
            with np.load(path) as f:
                if str(f["record_sha256"]) == sha:
                    return {k: f[k] for k in f.files}
        except Exception:  # a damaged cache file is rebuilt
            pass
    arrays = {"record_sha256": np.array(sha), **build()}
    buf = io.BytesIO()
    np.savez_compressed(buf, **arrays)
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, buf.getvalue())
    return arrays


def _one(job) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    data_dir, row, cache, derive, keep = job
    rec = load_record(Path(data_dir) / row["path"])
    arrays = cached_arrays(Path(cache) / row["path"], row["sha256"], lambda: derive(rec))
    return {k: rec[k] for k in keep}, arrays


def load_derived(data_dir: str | Path, rows: list[dict], cache: Path,
                 derive: Callable[[ShapeRecord], dict[str, np.ndarray]], keep: tuple[str, ...],
                 workers: int = 1) -> list[tuple[dict[str, np.ndarray], dict[str, np.ndarray]]]:
    """Per manifest row: (the record arrays named in ``keep``, its derived arrays).  ``derive``
    must be a module-level function (or partial of one) when ``workers`` > 1."""
    return process_map(_one, [(str(data_dir), r, str(cache), derive, keep) for r in rows], workers)
