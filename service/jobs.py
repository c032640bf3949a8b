"""What passes between the routers and the engine: immutable jobs in, results out.

A router turns a request's fields into a job (:class:`ImageJob`, :class:`ScanJob`, with the mesh
options every shape endpoint shares, :class:`MeshOptions`); the engine answers each job with a
result (:class:`ImageResult`, :class:`ScanResult`: the mesh and what was found on the way) or a
:class:`service.errors.ServiceError`, and never writes into the job.  A job's ``timer`` collects
its stages' times (the one mutable thing it carries, shared by the router and the engine).
"""

from __future__ import annotations

from dataclasses import dataclass

from model.image.frame import Framed
from model.octree.symmetry import Mirror
from model.surface import DEFAULT_SURFACE

from .meshes import MeshFile
from .metrics import StageTimer


@dataclass(frozen=True)
class MeshOptions:
    """How a shape endpoint answers: the file format, the decoded depth (None: the model's), the
    colours by depth, the surface (patches or watertight) and a face budget for the latter."""

    fmt: str
    depth: int | None = None
    color: bool = False
    surface: str = DEFAULT_SURFACE
    faces: int | None = None


@dataclass(frozen=True)
class ImageJob:
    """A photo to a shape: the upload's bytes, how to find the object (``remove_background``,
    ``box``: left, top, right, bottom in the upload's pixels, where to look for it) and frame it
    (``foreground_ratio``), and the mesh options."""

    data: bytes
    mesh: MeshOptions
    timer: StageTimer
    remove_background: str = "auto"
    foreground_ratio: float | None = None
    box: tuple[int, int, int, int] | None = None


@dataclass(frozen=True)
class ScanJob:
    """A partial scan to its completed shape: the upload (bytes, file name), whether the output
    keeps the scan's patches and reads a mirror-symmetric scan with its mirror image, the
    upload's up axis, and the mesh options."""

    data: bytes
    filename: str | None
    mesh: MeshOptions
    timer: StageTimer
    keep_scan: bool = True
    symmetry: bool = True
    up: str = "y"


@dataclass(frozen=True)
class ImageResult:
    """A photo's shape and its framing (mask source, crop box, mask)."""

    mesh: MeshFile
    framed: Framed


@dataclass(frozen=True)
class ScanResult:
    """A scan's completed shape, its mirror plane (None when not asked) and how many of its points
    far from the rest were dropped."""

    mesh: MeshFile
    mirror: Mirror | None
    strays: int
