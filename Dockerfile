# The Adaptive O-CNN inference service: FastAPI + onnxruntime, no torch.
#   docker build -t adaptive-ocnn .
#   docker run --rm -p 8000:8000 adaptive-ocnn          # then open http://localhost:8000/
# Settings are the AOCNN_* environment variables of README.md (e.g. -e AOCNN_CONCURRENCY=1
# -e AOCNN_THREADS=2 -e AOCNN_API_KEYS=...); more bundles: -v DIR:/models:ro -e AOCNN_MODELS_DIR=/models.
# Offline builds (no Docker Hub, no PyPI) pass BASE_IMAGE, PIP_NO_INDEX and PIP_FIND_LINKS as
# build arguments: see scripts/docker-smoke and docs/deploy.md.
ARG BASE_IMAGE=python:3.11-slim
FROM ${BASE_IMAGE}

# pip's own settings for the build only (default: PyPI); an offline build sets PIP_NO_INDEX=1 and PIP_FIND_LINKS
ARG PIP_NO_INDEX=0
ARG PIP_FIND_LINKS=
ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    VIRTUAL_ENV=/opt/venv \
    PATH=/opt/venv/bin:$PATH

# a virtual environment works the same on python:*-slim and on a Debian image with python3-venv
RUN python3 -m venv /opt/venv \
    && groupadd --system --gid 10001 aocnn \
    && useradd --system --uid 10001 --gid 10001 --no-create-home --home-dir /nonexistent \
       --shell /usr/sbin/nologin aocnn

WORKDIR /app
COPY pyproject.toml README.md constraints.txt ./
COPY model ./model
COPY export ./export
COPY service ./service
# the serving extra only: onnxruntime, FastAPI, uvicorn (no torch, no training or export tools), at
# the versions of constraints.txt; editable, so that the service finds examples/ and models/bundles/
# beside its package, as in a clone
RUN pip install --no-cache-dir -c constraints.txt -e ".[serve]" \
    && python3 -c "import importlib.util as u, sys; sys.exit(u.find_spec('torch') is not None)"
COPY examples ./examples
COPY models/bundles ./models/bundles
# the compiled kernels, once, at the build: a container (read-only, as user 10001) starts its kernel
# cache from this copy, so its warm-up loads them instead of compiling them where it runs on the
# build machine's kind of CPU (elsewhere they compile at the warm-up, as without it)
RUN NUMBA_CACHE_DIR=/opt/numba-seed python3 -m service --warm-up

USER 10001:10001
ENV AOCNN_HOST=0.0.0.0 \
    AOCNN_PORT=8000 \
    AOCNN_MODELS_DIR=/app/models/bundles \
    AOCNN_NUMBA_SEED=/opt/numba-seed
EXPOSE 8000
# ready = every bundle loaded, verified and warmed up (GET /readyz answers 200)
HEALTHCHECK --interval=15s --timeout=5s --start-period=120s --retries=3 \
    CMD ["python3", "-c", "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/readyz' % os.environ.get('AOCNN_PORT', '8000'), timeout=4)"]
CMD ["python3", "-m", "service"]
