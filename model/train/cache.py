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
from typing import Any, Callable

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


def _one(job) -> tuple[Any, dict[str, np.ndarray] | None]:
    data_dir, row, cache, derive, keep, derived, reduce = job
    path = Path(cache) / row["path"]
    if not derived and path.is_file():                  # only the record's arrays: read just those
        with np.load(Path(data_dir) / row["path"]) as rec:
            return reduce({k: rec[k] for k in keep}), None
    rec = load_record(Path(data_dir) / row["path"])
    arrays = cached_arrays(path, row["sha256"], lambda: derive(rec))
    return reduce({k: rec[k] for k in keep}), arrays if derived else None


def _as_is(arrays: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    return arrays


def load_derived(data_dir: str | Path, rows: list[dict], cache: Path,
                 derive: Callable[[ShapeRecord], dict[str, np.ndarray]], keep: tuple[str, ...],
                 workers: int = 1, derived: bool = True,
                 reduce: Callable[[dict[str, np.ndarray]], Any] = _as_is) -> list[tuple[Any, dict[str, np.ndarray] | None]]:
    """Per manifest row: (``reduce`` of the record arrays named in ``keep``: by default those
    arrays; its derived arrays, or None with ``derived=False``, which only makes sure the cache
    holds them).  ``derive`` and ``reduce`` must be module-level functions (or partials of them)
    when ``workers`` > 1; ``reduce`` runs in the worker, so only what it returns is held."""
    return process_map(_one, [(str(data_dir), r, str(cache), derive, keep, derived, reduce) for r in rows],
                       workers)


def derived_arrays(data_dir: str | Path, row: dict, cache: Path, keep: tuple[str, ...]
                   ) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """One row's (record arrays named in ``keep``, derived arrays), read from the dataset and the
    cache that :func:`load_derived` filled (a record streamed when its split is needed)."""
    with np.load(Path(data_dir) / row["path"]) as rec:
        kept = {k: rec[k] for k in keep}
    with np.load(Path(cache) / row["path"]) as f:
        if str(f["record_sha256"]) != row["sha256"]:
            raise ValueError(f"{Path(cache) / row['path']} was derived from another version of its record")
        return kept, {k: f[k] for k in f.files}
