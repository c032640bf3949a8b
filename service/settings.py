"""The service's one settings object, read from ``AOCNN_*`` environment variables.

Each limit is defined once: here for the service (with its allowed range), and where a limit
belongs to the octree core (the deepest octree it builds, :data:`MAX_BUILD_DEPTH`) the range
here is taken from there.  The README's table is :func:`settings_table` (a test keeps them equal),
and a bad value stops startup with one line naming the variable, the value and what is allowed
(:func:`describe_error`).
"""

from __future__ import annotations

from pathlib import Path

from annotated_types import Ge, Gt, Le, Lt
from pydantic import Field, ValidationError
from pydantic.fields import FieldInfo
from pydantic_settings import BaseSettings, SettingsConfigDict

from model.image.decode import MAX_PIXELS_DEFAULT
from model.octree.build import MAX_BUILD_DEPTH

DEFAULT_MODELS = Path(__file__).resolve().parents[1] / "models" / "bundles"
ENV_PREFIX = "AOCNN_"


def _shown(text: str) -> dict:
    """How the README shows a default that is computed or machine-dependent."""
    return {"json_schema_extra": {"shown_default": text}}


class Settings(BaseSettings):
    """Every limit and switch of the service; each field is ``AOCNN_<NAME>`` in the environment."""

    model_config = SettingsConfigDict(env_prefix=ENV_PREFIX, frozen=True)

    models_dir: Path = Field(DEFAULT_MODELS, description="folder whose sub-folders are the bundles to serve",
                             **_shown("`models/bundles` of the checkout"))
    host: str = Field("127.0.0.1", description="address uvicorn binds")
    port: int = Field(8000, ge=1, le=65535, description="port uvicorn binds")
    concurrency: int | None = Field(None, ge=1, description="inferences at once; CPUs = affinity capped by the "
                                    "cgroup quota", **_shown("CPUs / 2 (at least 1)"))
    threads: int | None = Field(None, ge=1, description="onnxruntime threads per inference (concurrency x threads "
                                "<= CPUs)", **_shown("CPUs / concurrency"))
    spinning: bool = Field(False, description="let idle onnxruntime threads busy-wait (off: they yield the CPU to "
                           "request parsing)")
    batch_window_ms: float = Field(0.0, ge=0, le=1000, description="dynamic batching: requests for one model "
                                   "arriving within this window (or while it is busy) run as one batch (0: off)")
    max_batch: int = Field(8, ge=1, le=64, description="largest dynamic batch")
    queue: int = Field(16, ge=0, description="requests that may wait for an inference slot; beyond that 503 with "
                       "Retry-After")
    timeout_s: float = Field(60.0, gt=0, description="per-request deadline (504 after it)")
    max_body_bytes: int = Field(32 << 20, ge=1024, description="request body limit (413)",
                                **_shown("33554432 (32 MiB)"))
    max_image_pixels: int = Field(MAX_PIXELS_DEFAULT, ge=1, description="image size limit, read from the header "
                                  "before decoding (413)")
    max_points: int = Field(1_000_000, ge=3, description="points per uploaded cloud (413; PLY and NPY headers are "
                            "checked first)")
    max_npz_bytes: int = Field(64 << 20, ge=1024, description="uncompressed size of an NPZ upload (zip bombs, 413)",
                               **_shown("67108864 (64 MiB)"))
    max_octree_depth: int = Field(8, ge=2, le=MAX_BUILD_DEPTH, description="deepest octree `/v1/octree` builds "
                                  "(422 above)")
    api_keys: str = Field("", description="comma-separated keys; when set, `/v1/*` needs `Authorization: Bearer "
                          "<key>` (401)", **_shown("empty (off)"))
    cors_origins: str = Field("", description="comma-separated origins allowed to call the API from a browser",
                              **_shown("empty"))

    def keys(self) -> set[str]:
        return {k.strip() for k in self.api_keys.split(",") if k.strip()}

    def origins(self) -> list[str]:
        return [o.strip() for o in self.cors_origins.split(",") if o.strip()]


def _bounds(field: FieldInfo) -> str:
    """The allowed values of a setting, from its type and its constraints."""
    annotation = field.annotation
    optional = str(annotation).endswith("| None")
    if annotation is bool:
        return "true or false"
    if annotation is Path:
        return "a folder"
    if annotation is str:
        return "text"
    kind = "an integer" if "int" in str(annotation) else "a number"
    parts = []
    for m in field.metadata:
        for cls, sign, attr in ((Ge, ">=", "ge"), (Gt, ">", "gt"), (Le, "<=", "le"), (Lt, "<", "lt")):
            if isinstance(m, cls):
                parts.append(f"{sign} {getattr(m, attr)}")
    text = f"{kind} {' and '.join(parts)}" if parts else kind
    return f"{text}, or unset" if optional else text


def _default(field: FieldInfo) -> str:
    extra = field.json_schema_extra or {}
    if "shown_default" in extra:
        return str(extra["shown_default"])
    value = field.default
    return str(value).lower() if isinstance(value, bool) else f"`{value}`" if isinstance(value, str) else str(value)


def settings_table() -> str:
    """The README's table of settings (Markdown), made from :class:`Settings` itself."""
    rows = ["| variable | default | allowed | meaning |", "| --- | --- | --- | --- |"]
    for name, field in Settings.model_fields.items():
        rows.append(f"| `{ENV_PREFIX}{name.upper()}` | {_default(field)} | {_bounds(field)} | {field.description} |")
    return "\n".join(rows) + "\n"


def describe_error(exc: ValidationError, options: dict[str, str] | None = None) -> str:
    """One line for settings that cannot start the service: each bad variable (or the command-line
    option that set it, listed in ``options``), the value given and what is allowed."""
    parts = []
    for e in exc.errors():
        name = str(e["loc"][0]) if e.get("loc") else ""
        field = Settings.model_fields.get(name)
        given = f"{options[name]} {e.get('input')}" if name in (options or {}) else \
            f"{ENV_PREFIX}{name.upper()}={e.get('input')}"
        allowed = f"; allowed: {_bounds(field)}" if field else ""
        parts.append(f"{given} is not valid ({e['msg'].lower()}){allowed}")
    return "; ".join(parts) or str(exc)
