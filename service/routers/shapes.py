"""The shape endpoints: photo -> shape, partial scan -> completed shape, shape -> its octree,
shape -> categories.  Uploads are multipart fields; the work runs in the engine's limiter."""

from __future__ import annotations

from typing import Annotated

import numpy as np
from fastapi import APIRouter, Depends, File, Header, Query, UploadFile
from fastapi.responses import Response
from pydantic import BaseModel, Field, model_validator

from export.bundle import Task
from model.formats import IMAGE_FORMATS
from model.image.frame import Framed, upload_box
from model.octree.build import MAX_BUILD_DEPTH
from model.octree.symmetry import MIN_SUPPORT, Mirror
from model.surface import DEFAULT_SURFACE

from ..deps import engine, require_key
from ..engine import Engine
from ..errors import ERROR_RESPONSES, ServiceError
from ..jobs import ImageJob, MeshOptions, ScanJob
from ..meshes import FORMATS, MeshFile, choose_format
from ..metrics import StageTimer
from ..schemas import ClassifyResponse, ClassScore, Debug, Format, RemoveBackground, Surface, Up

router = APIRouter(prefix="/v1", tags=["shapes"], dependencies=[Depends(require_key)])

MESH_RESPONSE = {200: {"description": "the mesh (headers: X-Surface, X-Mesh-Faces, X-Mesh-Closed)",
                       "content": {m: {} for m in FORMATS.values()}},
                 **ERROR_RESPONSES}
FRAMING_HEADERS = {
    "X-Mask": "where the object's mask came from: alpha (the image's transparency), network (the foreground "
              "network cut the object out of an opaque photo) or none (no mask: an opaque image cropped by its "
              "border colour)",
    "X-Crop-Box": "left,top,right,bottom (x0,y0,x1,y1, exclusive) of the object's box in the uploaded image's "
                  "pixels; absent when the whole image was used",
    "X-Mask-Confidence": "how sure the foreground network's mask is at its edge, 0 to 1 (the mean of |2p - 1| "
                         "about its outline); low: draw a box around the object (box=...); absent for other masks",
    "X-Foreground-Ratio": "the share of the encoder's square the object's longest side filled (3 decimals)"}
IMAGE_RESPONSE = {200: {"description": "the mesh (headers: X-Surface, X-Mesh-Faces, X-Mesh-Closed, X-Mask, "
                        "X-Crop-Box, X-Mask-Confidence, X-Foreground-Ratio); with debug=mask, the mask as an 8-bit "
                        "greyscale PNG of the image's size (the same framing headers)",
                        "content": {**{m: {} for m in FORMATS.values()}, "image/png": {}},
                        "headers": {k: {"description": d, "schema": {"type": "string"}}
                                    for k, d in FRAMING_HEADERS.items()}},
                  **ERROR_RESPONSES}
DEPTH_Q = Query(None, ge=1, le=MAX_BUILD_DEPTH, description="decode only down to this depth (a coarser, faster level "
                "of detail; the model's range is in GET /v1/models: min_depth..depth)")
REMOVE_BACKGROUND_Q = Query("auto", description="auto: an image with transparency uses its alpha, an opaque photo "
                            "the foreground network's mask (when the model has one, GET /v1/models: "
                            "foreground_network), else its border colour; true: the same, but an opaque photo is "
                            "refused (422 no_foreground_network) when the model has no foreground network; false: "
                            "never run the network (an opaque image is cropped by its border colour)")
FOREGROUND_RATIO_Q = Query(None, ge=0.3, le=1.0, description="the share of the encoder's square the object's longest "
                           "side fills (default the model's, GET /v1/models: foreground_ratio)")
KEEP_SCAN_Q = Query(True, description="true: where the scan has points the output keeps the scan's own patches (its "
                    "adaptive octree), and the network's patches fill everywhere the scan has none, down to the "
                    "finest octants; false: the network's output alone (it re-draws the scanned parts too, coarser)")
SYMMETRY_Q = Query(True, description="true: when the scan is mirror-symmetric across a left-right plane (x = c, "
                   f"the scan upright: +Y up, or +Z with up=z; at least {MIN_SUPPORT:.0%} of it landing on itself "
                   "mirrored, and not a flat sheet), it is completed from itself and its mirror image, so a side the "
                   "scanner missed starts from the side it saw; X-Symmetry says what was found; false: the scan as sent")
UP_Q = Query("y", description="the upload's up axis: y (the models' convention, as glTF and ShapeNet) or z (as CAD, "
             "most scanners and ModelNet40); a z-up shape is turned upright for the networks, which know objects "
             "standing on +Y, and a completed shape is turned back, so it comes in the upload's coordinates")
BOX_Q = Query(None, pattern=r"^-?\d+,-?\d+,-?\d+,-?\d+$", examples=["120,80,520,400"],
              description="where the object is: left,top,right,bottom (x0,y0,x1,y1) in the uploaded image's pixels, "
                          "as PIL and SAM-style tools write boxes; the object's mask is searched inside it only (the "
                          "network sees it with some of the photo about it; a "
                          "box partly beyond the image is clipped; 422 invalid_box for one outside it, no_object "
                          "for one that holds no object); with remove_background=false the box is the crop")
DEBUG_Q = Query(None, description="mask: answer with the mask the framing used (an 8-bit greyscale PNG of the "
                "image's size, 255 = object) instead of the mesh; 422 no_mask when there is none")


class MeshQuery(BaseModel):
    """The mesh options every shape endpoint takes (query parameters)."""

    model_config = {"extra": "ignore"}

    format: Format | None = Field(None, description="glb (default), gltf, ply or obj; an Accept header may choose "
                                  "too")
    surface: Surface = Field(DEFAULT_SURFACE, description="watertight: a closed, consistently oriented 2-manifold mesh "
                             "(it can be 3D-printed, voxelised or used as a collider); patches: the paper's output, one "
                             "planar patch per octree leaf, with cracks between them")
    faces: int | None = Field(None, ge=4, le=10_000_000, description="a face budget for the watertight surface: "
                              "simplified (staying closed) until it has at most this many faces")
    color_by_depth: bool = Field(False, description="colour the mesh by the octree depth of the leaf each vertex "
                                 "comes from")

    @model_validator(mode="after")
    def _faces_with_watertight(self) -> MeshQuery:
        if self.faces is not None and self.surface != "watertight":
            raise ValueError("faces applies to surface=watertight only (patches are one per leaf): drop faces, or "
                             "ask for surface=watertight")
        return self

    def options(self, accept: str | None, depth: int | None) -> MeshOptions:
        """The engine's mesh options of these parameters, the Accept header and a depth."""
        return MeshOptions(choose_format(self.format, accept), depth, self.color_by_depth, self.surface, self.faces)


MESH_Q = Annotated[MeshQuery, Query()]


def mesh_response(mesh: MeshFile, name: str, timer: StageTimer, model: str = "", version: str = "",
                  extra: dict[str, str] | None = None) -> Response:
    headers = {"Content-Disposition": f'attachment; filename="{name}.{mesh.extension}"',
               "X-Octree-Nodes": str(mesh.nodes),
               "X-Octree-Leaves": ",".join(f"{d}:{n}" for d, n in mesh.leaves.items()),
               "X-Surface": mesh.surface, "X-Mesh-Faces": str(mesh.faces),
               "X-Mesh-Closed": "true" if mesh.closed else "false", "Server-Timing": timer.header()}
    if model:
        headers |= {"X-Model-Name": model, "X-Model-Version": version}
    return Response(mesh.data, media_type=mesh.media_type, headers=headers | (extra or {}))


def framing_headers(framed: Framed, ratio: float) -> dict[str, str]:
    """X-Mask, X-Crop-Box (when there is a box; left, top, right, bottom), X-Mask-Confidence (a
    network's mask) and X-Foreground-Ratio of a photo's framing."""
    headers = {"X-Mask": framed.mask_source, "X-Foreground-Ratio": f"{ratio:.3f}"}
    box = upload_box(framed)
    if box is not None:
        top, left, bottom, right = box
        headers["X-Crop-Box"] = f"{left},{top},{right},{bottom}"
    if framed.confidence is not None:
        headers["X-Mask-Confidence"] = f"{framed.confidence:.3f}"
    return headers


async def _read(upload: UploadFile) -> tuple[bytes, str | None]:
    return await upload.read(), upload.filename


async def _submit(eng: Engine, task: Task, job):
    """Through the task's dynamic batcher; a job's own error is raised for it alone."""
    return await eng.batchers[task].submit(job)


@router.post("/image-to-shape", response_class=Response, responses=IMAGE_RESPONSE,
             summary="A photo of one object -> its 3D shape as a mesh (closed, or the leaf patches)")
async def image_to_shape(mesh: MESH_Q, image: UploadFile = File(..., description=f"{IMAGE_FORMATS} of one object"),
                         depth: int | None = DEPTH_Q, remove_background: RemoveBackground = REMOVE_BACKGROUND_Q,
                         foreground_ratio: float | None = FOREGROUND_RATIO_Q, box: str | None = BOX_Q,
                         debug: Debug | None = DEBUG_Q, accept: str | None = Header(None),
                         eng: Engine = Depends(engine)) -> Response:
    b = eng.model(Task.IMAGE_TO_SHAPE).bundle
    data, _ = await _read(image)
    timer = StageTimer(eng.metrics)
    region = None if box is None else tuple(int(v) for v in box.split(","))
    job = ImageJob(data, mesh.options(accept, depth), timer, remove_background, foreground_ratio, region)
    ratio = b.image_spec().foreground_ratio if foreground_ratio is None else foreground_ratio
    if debug == "mask":                  # only the framing: no encoder, no decoder
        eng.check_depth(eng.model(Task.IMAGE_TO_SHAPE), depth)
        png, framed = await eng.limiter.run(lambda: eng.mask_png(job), eng.settings.timeout_s)
        headers = {"Content-Disposition": 'inline; filename="mask.png"', "Server-Timing": timer.header(),
                   "X-Model-Name": b.name, "X-Model-Version": b.version}
        return Response(png, media_type="image/png", headers=headers | framing_headers(framed, ratio))
    result = await _submit(eng, Task.IMAGE_TO_SHAPE, job)
    return mesh_response(result.mesh, "shape", timer, b.name, b.version, framing_headers(result.framed, ratio))


@router.post("/complete", response_class=Response, responses=MESH_RESPONSE,
             summary="A partial, noisy point cloud -> the completed shape, in the input's coordinates")
async def complete(mesh: MESH_Q,
                   points: UploadFile = File(..., description="PLY (ascii/binary), XYZ/TXT, NPY, NPZ or OBJ "
                                             "vertices, with or without normals; points far from the rest (at "
                                             "most a tenth of them, beyond an empty gap to 3 times the rest's "
                                             "radius: flying pixels, a reflection) are dropped, and "
                                             "X-Points-Dropped says how many"),
                   depth: int | None = DEPTH_Q, keep_scan: bool = KEEP_SCAN_Q, symmetry: bool = SYMMETRY_Q,
                   up: Up = UP_Q, accept: str | None = Header(None), eng: Engine = Depends(engine)) -> Response:
    b = eng.model(Task.COMPLETION).bundle
    data, filename = await _read(points)
    timer = StageTimer(eng.metrics)
    job = ScanJob(data, filename, mesh.options(accept, depth), timer, keep_scan, symmetry, up)
    result = await _submit(eng, Task.COMPLETION, job)
    return mesh_response(result.mesh, "completed", timer, b.name, b.version,
                         {"X-Keep-Scan": "true" if keep_scan else "false", "X-Symmetry": symmetry_header(result.mirror),
                          "X-Points-Dropped": str(result.strays)})


def symmetry_header(mirror: Mirror | None) -> str:
    """X-Symmetry: "off" (not asked), else whether the scan was mirrored (a sheet never is), its
    plane in the scan's coordinates and the plane's support."""
    if mirror is None:
        return "off"
    used = "mirrored" if mirror.supported() else "not mirrored (a sheet)" if mirror.sheet else "not mirrored"
    return f"{used}; plane x={mirror.offset:.6g}; support={mirror.support:.3f}"


@router.post("/octree", response_class=Response, responses=MESH_RESPONSE,
             summary="A mesh or point cloud -> the surface of its patch-guided adaptive octree (no learning)")
async def octree(mesh: MESH_Q,
                 shape: UploadFile = File(..., description="a mesh (OBJ, OFF, STL, PLY, GLB, glTF) or a point "
                                          "cloud; a cloud's points far from the rest are dropped (X-Points-Dropped "
                                          "says how many; see /v1/complete)"),
                 depth: int = Query(6, ge=2, le=MAX_BUILD_DEPTH, description="octree depth (at most "
                                    "AOCNN_MAX_OCTREE_DEPTH, 8 by default)"),
                 threshold: float | None = Query(None, gt=0, le=64, description="split threshold in finest voxels "
                                                 "(default the paper's sqrt(3)/2)"),
                 full: bool = Query(False, description="the full O-CNN octree instead of the adaptive one"),
                 accept: str | None = Header(None), eng: Engine = Depends(engine)) -> Response:
    if depth > eng.settings.max_octree_depth:
        raise ServiceError("invalid_depth", f"depth must be at most {eng.settings.max_octree_depth}, got {depth}",
                           "ask for a smaller depth (or raise AOCNN_MAX_OCTREE_DEPTH)")
    data, filename = await _read(shape)
    options = mesh.options(accept, depth)
    timer = StageTimer(eng.metrics)
    result, strays = await eng.limiter.run(lambda: eng.octree(data, filename, threshold, full, options, timer),
                                           eng.settings.timeout_s)
    return mesh_response(result, "octree", timer, extra={"X-Points-Dropped": str(strays)})


@router.post("/classify", response_model=ClassifyResponse, responses=ERROR_RESPONSES,
             summary="A mesh or point cloud -> its most likely categories",
             description="With vote=true the shape is classified at 12 rotations about the up axis (the "
                         "paper's test-time vote): each probability is the mean over the rotations, and "
                         "`votes` counts the rotations that rank the category first. A voted probability is "
                         "lower than a single view's whenever some rotations disagree; the vote's answer is "
                         "the more accurate one (the model card's test figures).")
async def classify(response: Response, shape: UploadFile = File(..., description="a mesh or point cloud; a cloud's "
                                                                   "points far from the rest are dropped "
                                                                   "(X-Points-Dropped says how many)"),
                   top_k: int = Query(5, ge=1, le=50, description="how many categories to return"),
                   vote: bool = Query(False, description="average over 12 rotations about the up axis "
                                      "(the paper's test-time vote; 12x the work)"),
                   up: Up = UP_Q,
                   eng: Engine = Depends(engine)) -> ClassifyResponse:
    b = eng.model(Task.CLASSIFY).bundle
    data, filename = await _read(shape)
    timer = StageTimer(eng.metrics)
    probs, strays = await eng.limiter.run(lambda: eng.classify(data, filename, vote, timer, up), eng.settings.timeout_s)
    response.headers["Server-Timing"] = timer.header()
    response.headers["X-Points-Dropped"] = str(strays)
    mean, votes = probs.mean(0), np.bincount(probs.argmax(1), minlength=probs.shape[1])
    order = np.argsort(-mean, kind="stable")[:top_k]
    return ClassifyResponse(model=b.name, version=b.version, rotations=len(probs),
                            top=[ClassScore(category=b.categories[i], probability=min(1.0, max(0.0, float(mean[i]))),
                                            votes=int(votes[i])) for i in order])
