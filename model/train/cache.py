"""Derived training data cached beside a dataset: one .npz per record, keyed by the record's
checksum and the settings that derived it, built in parallel on first use and rebuilt when stale.

Tasks whose inputs are expensive to derive from a record (completion's partial-scan octrees,
classification's rotated octrees) cache them here so reruns and resumed runs start in seconds.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path
from typing import Any, Callable, TypeVar

import numpy as np

from ..data.dataset import ShapeRecord, load_record
from ..files import npz_bytes, write_atomic
from .data import READ_ERRORS, process_map

T = TypeVar("T")


def cache_dir(data_dir: str | Path, name: str, settings: dict) -> Path:
    """``<data>/cache/<name>-<fingerprint of settings>``."""
    key = hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:12]
    return Path(data_dir) / "cache" / f"{name}-{key}"


def cached_arrays(path: Path, sha: str, build: Callable[[], dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """The arrays cached at ``path`` for the record of checksum ``sha``, built and written
    atomically when missing, stale or unreadable."""
    cached = read_cached(path, sha, lambda f: {k: f[k] for k in f.files})
    if cached is not None:
        return cached
    arrays = {"record_sha256": np.array(sha), **build()}
    path.parent.mkdir(parents=True, exist_ok=True)
    write_atomic(path, npz_bytes(arrays))
    return arrays


def read_cached(path: Path, sha: str, read: Callable[[Any], T]) -> T | None:
    """``read`` of the open cache file at ``path`` (an ``np.load`` of it: each array read when
    asked for), or None when the file is missing, stale or damaged."""
    try:
        with np.load(path) as f:
            return read(f) if str(f["record_sha256"]) == sha else None
    except READ_ERRORS:          # missing, or damaged anywhere: zip, zlib or array format
        return None


def derived_arrays(data_dir: str | Path, row: dict, cache: str | Path,
                   derive: Callable[[ShapeRecord], dict[str, np.ndarray]], keep: tuple[str, ...],
                   derived: bool = True) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray] | None]:
    """One row's (record arrays named in ``keep``, derived arrays): only those arrays are read
    from the record, and the whole record only when the cache must be (re)built.  With
    ``derived=False`` the derived arrays are not read when the cache has them (None)."""
    record = Path(data_dir) / row["path"]
    with np.load(record) as rec:
        kept = {k: rec[k] for k in keep}
    path = Path(cache) / row["path"]
    if not derived and path.is_file():
        return kept, None
    arrays = cached_arrays(path, row["sha256"], lambda: derive(load_record(record)))
    return kept, arrays if derived else None


def _one(job) -> tuple[Any, dict[str, np.ndarray] | None]:
    data_dir, row, cache, derive, keep, derived, reduce = job
    kept, arrays = derived_arrays(data_dir, row, cache, derive, keep, derived)
    return reduce(kept), arrays


def _as_is(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return arrays


def load_derived(data_dir: str | Path, rows: list[dict], cache: Path,
                 derive: Callable[[ShapeRecord], dict[str, np.ndarray]], keep: tuple[str, ...],
                 workers: int = 1, derived: bool = True,
                 reduce: Callable[[dict[str, np.ndarray]], Any] = _as_is) -> list[tuple[Any, dict[str, np.ndarray] | None]]:
    """Per manifest row: (``reduce`` of the record arrays named in ``keep``: by default those
    arrays; its derived arrays, or None with ``derived=False``, which only makes sure the cache
    holds them: :func:`derived_arrays` reads a row again when it is needed).  ``derive`` and
    ``reduce`` must be module-level functions (or partials of them) when ``workers`` > 1;
    ``reduce`` runs in the worker, so only what it returns is held."""
    return process_map(_one, [(str(data_dir), r, str(cache), derive, keep, derived, reduce) for r in rows],
                       workers)
