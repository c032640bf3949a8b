"""Training data for Adaptive O-CNN: procedural ShapeNet-like shapes, virtual scans,
partial scans, 3D-R2N2-style renders and loaders for real dataset layouts."""

from .layouts import (
    MeshRecord,
    RenderRecord,
    ViewMetadata,
    iter_modelnet40,
    iter_r2n2,
    iter_shapenet,
    load_mesh,
    read_off,
)
from .partial import partial_from_scan, partial_indices, partial_scan
from .render import composite, metadata_row, render, render_views
from .scanner import Scan, scan, scan_detailed, scanner_directions
from .shapes import CATEGORIES, SYNSETS, generate, split_of

__all__ = [
    "CATEGORIES", "SYNSETS", "generate", "split_of",
    "Scan", "scan", "scan_detailed", "scanner_directions",
    "render", "render_views", "composite", "metadata_row",
    "partial_scan", "partial_from_scan", "partial_indices",
    "MeshRecord", "RenderRecord", "ViewMetadata", "iter_modelnet40", "iter_shapenet", "iter_r2n2",
    "load_mesh", "read_off",
]
