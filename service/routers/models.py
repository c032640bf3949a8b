"""GET /v1/models: what the service serves, with checksums and test figures."""

from __future__ import annotations

from fastapi import APIRouter, Depends

from export.bundle import Task

from ..deps import engine, require_key
from ..engine import Engine
from ..schemas import GraphInfo, ModelInfo, ModelsResponse

router = APIRouter(prefix="/v1", tags=["models"], dependencies=[Depends(require_key)])


@router.get("/models", response_model=ModelsResponse, summary="The served models' metadata and checksums")
async def models(eng: Engine = Depends(engine)) -> ModelsResponse:
    out = []
    for served in eng.models.values():
        b = served.bundle
        image = b.task == Task.IMAGE_TO_SHAPE
        out.append(ModelInfo(task=b.task, name=b.name, version=b.version, depth=b.octree.depth,
                             min_depth=b.octree.adaptive_depth, input=b.input, categories=b.categories,
                             graphs={n: GraphInfo(file=g.file, sha256=g.sha256) for n, g in b.graphs.items()},
                             evaluation=b.meta.get("evaluation"),
                             foreground_network=served.runtime.has_foreground if image else None,
                             foreground_ratio=round(b.image_spec().foreground_ratio, 6) if image else None))
    return ModelsResponse(models=out)
