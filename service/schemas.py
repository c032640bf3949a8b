"""Request and response models of the API (they make the OpenAPI schema at /docs)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, Field

Format = Literal["glb", "gltf", "ply", "obj"]
Surface = Literal["watertight", "patches"]
RemoveBackground = Literal["auto", "true", "false"]       # model.image.frame.REMOVE_BACKGROUND
Debug = Literal["mask"]
Up = Literal["y", "z"]                                     # model.octree.geometry.to_y_up


class GraphInfo(BaseModel):
    file: str
    sha256: str = Field(examples=["3f0c…"])


class ModelInfo(BaseModel):
    """One served bundle."""

    task: str = Field(examples=["image-to-shape"])
    name: str
    version: str = Field(examples=["0.1.0+eb0466a052b7"])
    depth: int = Field(description="the deepest octree level the model decodes", examples=[6])
    min_depth: int = Field(description="the coarsest level of detail a request may ask for", examples=[4])
    input: dict = Field(description="the input spec (image preprocessing or point limits)")
    categories: list[str]
    graphs: dict[str, GraphInfo]
    evaluation: dict | None = Field(None, description="the checkpoint's test figures")
    foreground_network: bool | None = Field(None, description="image-to-shape: whether the model has a foreground "
                                            "network, which removes the background of opaque photos "
                                            "(remove_background=auto|true); null for other tasks")
    foreground_ratio: float | None = Field(None, description="image-to-shape: the default share of the encoder's "
                                           "square the object's longest side fills; null for other tasks",
                                           examples=[0.9])


class ModelsResponse(BaseModel):
    models: list[ModelInfo]


class Health(BaseModel):
    status: Literal["ok"] = "ok"


class Readiness(BaseModel):
    ready: bool
    models: list[str] = Field(description="tasks served once ready", examples=[["image-to-shape"]])


class ClassScore(BaseModel):
    category: str
    probability: float = Field(ge=0, le=1, description="the softmax probability; with vote=true, its mean over the "
                               "12 rotations (lower than a single view's when the rotations disagree)")
    votes: int = Field(ge=0, description="how many of the rotations rank this category first (1 or 0 without "
                       "the vote)")


class ClassifyResponse(BaseModel):
    model: str
    version: str
    rotations: int = Field(description="the rotations about the up axis the answer averages: 12 with vote=true, "
                           "else 1", examples=[12])
    top: list[ClassScore]
