"""Procedural part-based shapes for the 13 ShapeNet categories of the paper.

ShapeNet cannot be downloaded here, so each category has a parametric
generator with randomised proportions, part counts and styles.

Conventions (as ShapeNetCore.v2 ``model_normalized``): +Y is up, the shape
faces +Z (front; nose/muzzle/bow/screen towards +Z), the bounding box is
centred at the origin and its longest edge has length 1.  Meshes are polygon
soups: overlapping closed parts concatenated without boolean union.
``generate(category, index, seed)`` is deterministic: its generator is seeded
from a SHA-256 hash of the three values (never Python's salted ``hash``).  The generators have
versions (:data:`GENERATORS`); a version's shapes never change once models were trained on them.
"""

from __future__ import annotations

import hashlib

import numpy as np
import trimesh

from .devices import display, lamp, loudspeaker, telephone
from .furniture import bench, cabinet, chair, chair_wider, sofa, table
from .vehicles import airplane, car, rifle, watercraft

CATEGORIES: tuple[str, ...] = (
    "airplane", "bench", "cabinet", "car", "chair", "display", "lamp",
    "loudspeaker", "rifle", "sofa", "table", "telephone", "watercraft",
)
SYNSETS: dict[str, str] = {
    "airplane": "02691156", "bench": "02828884", "cabinet": "02933112", "car": "02958343",
    "chair": "03001627", "display": "03211117", "lamp": "03636649", "loudspeaker": "03691459",
    "rifle": "04090263", "sofa": "04256520", "table": "04379232", "telephone": "04401088",
    "watercraft": "04530566",
}
_GENERATORS = {
    "airplane": airplane, "bench": bench, "cabinet": cabinet, "car": car, "chair": chair,
    "display": display, "lamp": lamp, "loudspeaker": loudspeaker, "rifle": rifle, "sofa": sofa,
    "table": table, "telephone": telephone, "watercraft": watercraft,
}
_WIDER = {"chair": chair_wider}
GENERATORS: dict[int, str] = {
    1: "the shapes every shipped model was trained on",
    2: "the first's, with chairs also folding, on side slabs, cantilevered or upholstered club "
       "armchairs (kinds real chairs showed the first lacking)",
}
"""The generator versions: version -> what it makes."""
SPLIT_FRACTIONS: tuple[float, float, float] = (0.8, 0.1, 0.1)


def stable_hash(*parts: object) -> int:
    """64-bit integer from SHA-256 of the parts' text; identical across runs and machines."""
    text = "\x1f".join(str(p) for p in parts).encode("utf-8")
    return int.from_bytes(hashlib.sha256(text).digest()[:8], "little")


def split_from_key(*parts: object, fractions: tuple[float, float, float] = SPLIT_FRACTIONS) -> str:
    """Deterministic "train"/"val"/"test" assignment of a key by its stable hash."""
    x = (stable_hash("split", *parts) % 1_000_000) / 1_000_000
    if x < fractions[0]:
        return "train"
    return "val" if x < fractions[0] + fractions[1] else "test"


def check_category(category: str) -> str:
    """Return ``category`` if known, else raise ValueError listing the valid names."""
    if category not in _GENERATORS:
        raise ValueError(f"unknown category {category!r}; valid categories: {', '.join(CATEGORIES)}")
    return category


def generate(category: str, index: int, seed: int = 0, generator: int = 1) -> trimesh.Trimesh:
    """Generate shape ``index`` of ``category`` with generator version ``generator``
    (:data:`GENERATORS`); deterministic in (category, index, seed, generator), and the same shape
    for every version where that version does not change the category.

    Returns a polygon-soup Trimesh normalised as described in the module docstring.
    """
    check_category(category)
    if generator not in GENERATORS:
        raise ValueError(f"unknown generator {generator!r}; versions: {', '.join(map(str, GENERATORS))}")
    rng = np.random.default_rng(stable_hash("shape", category, int(index), int(seed)))
    make = _WIDER.get(category, _GENERATORS[category]) if generator >= 2 else _GENERATORS[category]
    return make(rng).mesh()


def split_of(category: str, index: int, seed: int = 0) -> str:
    """Fixed 80/10/10 train/val/test split of generated shapes by a stable hash."""
    check_category(category)
    return split_from_key(category, int(index), int(seed))


__all__ = ["CATEGORIES", "GENERATORS", "SYNSETS", "SPLIT_FRACTIONS", "generate", "split_of", "split_from_key", "stable_hash",
           "check_category"]
