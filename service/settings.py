"""The service's one settings object, read from ``AOCNN_*`` environment variables."""

from __future__ import annotations

from pathlib import Path

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

DEFAULT_MODELS = Path(__file__).resolve().parents[1] / "models" / "bundles"


class Settings(BaseSettings):
    """Every limit and switch of the service; each field is ``AOCNN_<NAME>`` in the environment."""

    model_config = SettingsConfigDict(env_prefix="AOCNN_", frozen=True)

    models_dir: Path = Field(DEFAULT_MODELS, description="folder whose sub-folders are bundles to serve")
    host: str = Field("127.0.0.1", description="address uvicorn binds")
    port: int = Field(8000, ge=1, le=65535, description="port uvicorn binds")
    threads: int | None = Field(None, ge=1, description="onnxruntime intra-op threads per inference "
                                "(default: the CPUs the process may use / concurrency)")
    concurrency: int | None = Field(None, ge=1, description="inferences run at once (default: 1 per 2 CPUs, at least 1)")
    spinning: bool = Field(False, description="let idle onnxruntime threads busy-wait for work (measured: bench.load)")
    batch_window_ms: float = Field(0.0, ge=0, le=1000, description="dynamic batching: wait this long for more "
                                   "requests to batch with (0: off; measured: bench.load)")
    max_batch: int = Field(8, ge=1, le=64, description="largest dynamic batch")
    queue: int = Field(16, ge=0, description="requests that may wait for an inference slot; more get 503")
    timeout_s: float = Field(60.0, gt=0, description="a request that has not finished by then gets 504")
    max_body_bytes: int = Field(32 << 20, ge=1024, description="request body size limit (413 above)")
    max_image_pixels: int = Field(40_000_000, ge=1, description="image pixel count limit, checked from the header")
    max_points: int = Field(1_000_000, ge=3, description="point count limit of uploaded clouds")
    max_npz_bytes: int = Field(64 << 20, ge=1024, description="uncompressed size limit of an NPZ upload")
    max_octree_depth: int = Field(8, ge=2, le=10, description="deepest octree /v1/octree builds")
    api_keys: str = Field("", description="comma-separated API keys; empty: no authentication")
    cors_origins: str = Field("", description="comma-separated origins allowed by CORS (e.g. the demo page's)")

    def keys(self) -> set[str]:
        return {k.strip() for k in self.api_keys.split(",") if k.strip()}

    def origins(self) -> list[str]:
        return [o.strip() for o in self.cors_origins.split(",") if o.strip()]
