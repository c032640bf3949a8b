"""Where the real test meshes live, resolved one way for every test: ``AOCNN_SHARED_MESHES`` if
set, else ``shared/meshes`` beside the checkout (research-use meshes, never copied into the repo)."""

from __future__ import annotations

import os
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED_MESHES = Path(os.environ.get("AOCNN_SHARED_MESHES") or REPO.parent / "shared" / "meshes")
