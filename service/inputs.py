"""Uploaded inputs to arrays, with limits: images through the shared preprocessing, point clouds
and meshes through the octree core's loader.  Formats are recognised from the bytes
(:func:`model.formats.identify`: a lying Content-Type or file name changes nothing, and a file of
a kind the endpoint does not take is named in its 415); pickled arrays are never unpickled;
temporary files are removed whatever happens.
"""

from __future__ import annotations

import dataclasses
import io
import re
import tempfile
import zipfile
from pathlib import Path

from model.formats import IMAGE_FORMATS, MESH_FORMATS, POINT_FORMATS, identify, not_taken
from model.image.decode import ImageError, decode_photo
from model.image.frame import Framed, ImageSpec, frame_object, region_of
from model.image.mask import MaskSpec, NoObjectError
from model.octree import OctreeInputError
from model.octree.inputs import HEADER_BYTES, LoadedInput, load_input, ply_vertex_count
from model.octree.pointcloud import Beside

from .errors import ServiceError

POINTS_TAKEN = f"this endpoint takes a point cloud ({POINT_FORMATS})"
SHAPES_TAKEN = f"this endpoint takes a mesh ({MESH_FORMATS}) or a point cloud ({POINT_FORMATS})"
IMAGES_TAKEN = f"this endpoint takes an image ({IMAGE_FORMATS})"


def image_input(data: bytes, spec: ImageSpec, max_pixels: int, segment=None, remove_background: str = "auto",
                foreground_ratio: float | None = None, mask_spec: MaskSpec = MaskSpec(), refine=None,
                box: tuple[int, int, int, int] | None = None) -> Framed:
    """An uploaded image decoded (a large photo reduced as it is decoded:
    :func:`model.image.decode.decode_photo`) and framed for the encoder
    (:func:`model.image.frame.frame_object`: ``segment`` is the foreground network, None without
    one, ``refine`` its refinement network; ``box``: left, top, right, bottom in the upload's pixels,
    where to look for the object; the upload's size kept on the result), or a 4xx (415 naming what
    else it is, 422 when it shows no object, the box holds none or lies outside the image, or it
    asks for a background removal the model cannot do)."""
    if not data:
        raise ServiceError("empty_input", "the 'image' field is empty", "upload the image file's bytes")
    try:
        decoded = decode_photo(data, max_pixels)
        try:
            region = None if box is None else region_of(box, decoded.size, decoded.rgba.shape[:2])
        except ImageError as exc:
            raise ServiceError("invalid_box", str(exc), "give box=left,top,right,bottom in the image's pixels, "
                               "around the object") from None
        framed = frame_object(decoded.rgba, spec, segment, remove_background, foreground_ratio, mask_spec, refine,
                              region)
        return dataclasses.replace(framed, size=decoded.size)
    except NoObjectError as exc:
        hint = ("draw the box around the object" if str(exc).startswith("the box holds no object") else
                "send a photo where one object stands out from its background, or a PNG with transparency "
                "around the object")
        raise ServiceError("no_object", str(exc), hint) from None
    except ImageError as exc:
        message = str(exc)
        if message.startswith("remove_background=true needs a foreground network"):
            raise ServiceError("no_foreground_network", message, "send an image with transparency around the "
                           "object, or use remove_background=auto") from None
        if "more than the limit" in message:
            raise ServiceError("image_too_large", message, "send a smaller image (downscale it)") from None
        if "not an image" in message:
            kind = identify(data)
            what = (f"this is {kind.name} that Pillow cannot decode; {IMAGES_TAKEN}" if kind.family == "image"
                    else not_taken(kind, IMAGES_TAKEN))
            raise ServiceError("unsupported_image", what, "send a photo of one object as PNG or JPEG") from None
        raise ServiceError("invalid_image", message, "send a complete, readable photo of one object") from None


def _check_size(data: bytes, fmt: str, max_points: int, max_npz_bytes: int) -> None:
    """Refuse from headers what would decode to too much, before decoding it."""
    if fmt == "npz":
        try:
            total = sum(i.file_size for i in zipfile.ZipFile(io.BytesIO(data)).infolist())
        except zipfile.BadZipFile:
            raise ServiceError("invalid_points", "the NPZ archive is corrupt", "send a file written by numpy.savez") from None
        if total > max_npz_bytes:
            raise ServiceError("input_too_large", f"the NPZ archive unpacks to {total:,} bytes, more than the "
                           f"limit of {max_npz_bytes:,}", "send fewer points")
    elif fmt == "ply":
        declared = ply_vertex_count(data[:HEADER_BYTES])
        if declared is not None and declared > max_points:
            raise ServiceError("too_many_points", f"the PLY header declares {declared:,} vertices, more "
                           f"than the limit of {max_points:,}", "subsample the cloud")
    elif fmt == "npy":
        m = re.search(rb"'shape':\s*\((\d+)", data[:512])
        if m and int(m.group(1)) > max_points:
            raise ServiceError("too_many_points", f"the array has {int(m.group(1)):,} rows, more than the limit "
                           f"of {max_points:,}", "subsample the cloud")


def shape_input(data: bytes, filename: str | None, depth: int, max_points: int, max_npz_bytes: int,
                field: str = "points", beside: Beside | None = None) -> LoadedInput:
    """Oriented points of an uploaded point cloud (field ``points``) or mesh or point cloud (field
    ``shape``), normals estimated when absent, or a 4xx: 415 for a kind of file the endpoint does
    not take, 413 over a limit, 400 for a taken kind that is malformed or unusable.  ``beside``:
    work on the checked points, run beside their normals' orientation (:data:`Beside`)."""
    if not data:
        raise ServiceError("empty_input", f"the '{field}' field is empty", "upload the file's bytes")
    kind = identify(data, filename)
    takes = POINTS_TAKEN if field == "points" else SHAPES_TAKEN
    if kind.loader is None:
        raise ServiceError("unsupported_format", not_taken(kind, takes), "convert it to one of those formats")
    fmt = kind.loader
    _check_size(data, fmt, max_points, max_npz_bytes)
    with tempfile.TemporaryDirectory(prefix="aocnn-") as tmp:
        path = Path(tmp) / f"upload.{fmt}"
        path.write_bytes(data)
        try:
            loaded = load_input(str(path), depth, beside=beside)
        except OctreeInputError as exc:
            message = str(exc).replace(str(path), f"the {fmt.upper()} upload").replace(tmp, "the upload folder")
            raise ServiceError("invalid_points", message, f"{takes[5:]}, with real coordinates") from None
    n = len(loaded.cloud.points)
    if loaded.kind == "points" and n > max_points:
        raise ServiceError("too_many_points", f"the upload has {n:,} points, more than the limit of {max_points:,}",
                       "subsample the cloud")
    return loaded
