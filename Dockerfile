# syntax=docker/dockerfile:1
# The sdcnet inference service (sdc-serve) with the shipped model baked in.
#
#   docker build -t sdcnet .                     # CPU image (the default target)
#   docker build --target cuda -t sdcnet:cuda .  # onnxruntime-gpu on an NVIDIA CUDA runtime
#   docker build --target data -t sdcnet:data .  # the dataset generator, sdc-data (deploy/)
#   docker run --rm -p 8000:8000 sdcnet
#   docker run --rm --gpus all -p 8000:8000 sdcnet:cuda
#
# The project is installed as CI installs it (same package, constraints and extras; no torch):
# pip install -c constraints.txt '.[serve,client]'. Needs models/sdcnet.onnx (sdc-export).
# Settings are SDCNET_* environment variables (see the README), e.g. -e SDCNET_THREADS=2.

ARG PYTHON_IMAGE=python:3.11-slim
ARG CUDA_IMAGE=nvidia/cuda:12.6.3-cudnn-runtime-ubuntu24.04
# onnxruntime-gpu wheels are built for one CUDA major (1.19-1.22: CUDA 12 with cuDNN 9): keep the
# two arguments in step when changing either.
ARG ONNXRUNTIME_GPU_VERSION=1.22.0

# ---------------------------------------------------------------------------------------------
# Sources of the package; nothing else of the repository enters an image.
FROM ${PYTHON_IMAGE} AS source
WORKDIR /src
COPY pyproject.toml constraints.txt README.md ./
COPY sdcnet/ sdcnet/
COPY training/ training/
COPY evaluation/ evaluation/
COPY export/ export/
COPY service/ service/
COPY client/ client/
COPY models/ models/
RUN test -f models/sdcnet.onnx \
    || { echo "models/sdcnet.onnx is missing: export the model first (sdc-export)" >&2; exit 1; }

# ---------------------------------------------------------------------------------------------
# CPU: a virtual environment built here, copied alone into a clean slim image (no compilers,
# no pip cache, no sources).
# The import check runs with -P: from /src, a plain python -c would import the source folder
# sdcnet/ (no service/ in it) instead of the installed package.
FROM source AS build
RUN python -m venv /opt/venv \
    && /opt/venv/bin/pip install --no-cache-dir --disable-pip-version-check \
        -c constraints.txt '.[serve,client]' \
    && /opt/venv/bin/python -P -c "import sdcnet.service.app, sdcnet.client.cli, sdcnet.models"

# ---------------------------------------------------------------------------------------------
# CUDA: the same install on the CUDA base (its Python), with onnxruntime-gpu in place of
# onnxruntime (both provide the onnxruntime module; only one may be installed).
FROM ${CUDA_IMAGE} AS cuda-build
ARG ONNXRUNTIME_GPU_VERSION
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 python3-venv \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY --from=source /src /src
RUN python3 -m venv /opt/venv \
    && /opt/venv/bin/pip install --no-cache-dir --disable-pip-version-check \
        -c constraints.txt '.[serve,client]' \
    && /opt/venv/bin/pip uninstall -y onnxruntime \
    && /opt/venv/bin/pip install --no-cache-dir --disable-pip-version-check \
        "onnxruntime-gpu==${ONNXRUNTIME_GPU_VERSION}" \
    && /opt/venv/bin/python -P -c "import sdcnet.service.app, sdcnet.client.cli, sdcnet.models"

FROM ${CUDA_IMAGE} AS cuda
# hadolint ignore=DL3008
RUN apt-get update \
    && apt-get install -y --no-install-recommends python3 \
    && rm -rf /var/lib/apt/lists/* \
    && groupadd --system --gid 10001 sdcnet \
    && useradd --system --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin sdcnet
COPY --from=cuda-build /opt/venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    HOME=/tmp \
    SDCNET_HOST=0.0.0.0 \
    SDCNET_PORT=8000
USER 10001:10001
EXPOSE 8000
HEALTHCHECK --interval=15s --timeout=5s --start-period=60s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request as u; u.urlopen('http://127.0.0.1:%s/v2/health/ready' % os.environ.get('SDCNET_PORT', '8000'), timeout=4)"]
CMD ["sdc-serve"]

# ---------------------------------------------------------------------------------------------
# The dataset generator (sdc-data), to render a dataset on a cluster (deploy/dataset-job.yaml):
# the data extra (trimesh, embreex, scipy) in place of the service; no torch, no model.
FROM source AS data-build
RUN python -m venv /opt/venv \
    && /opt/venv/bin/pip install --no-cache-dir --disable-pip-version-check \
        -c constraints.txt '.[data]' \
    && /opt/venv/bin/python -P -c "import sdcnet.training.data.cli"

FROM ${PYTHON_IMAGE} AS data
RUN groupadd --system --gid 10001 sdcnet \
    && useradd --system --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin sdcnet
COPY --from=data-build /opt/venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    HOME=/tmp
USER 10001:10001
ENTRYPOINT ["sdc-data"]
CMD ["--help"]

# ---------------------------------------------------------------------------------------------
# The CPU runtime image: last, so that it is the default target.
FROM ${PYTHON_IMAGE} AS cpu
RUN groupadd --system --gid 10001 sdcnet \
    && useradd --system --uid 10001 --gid 10001 --no-create-home --shell /usr/sbin/nologin sdcnet
COPY --from=build /opt/venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    HOME=/tmp \
    SDCNET_HOST=0.0.0.0 \
    SDCNET_PORT=8000
USER 10001:10001
EXPOSE 8000
# Readiness (model loaded), with the Python already in the image: the slim base has no curl.
HEALTHCHECK --interval=15s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import os, urllib.request as u; u.urlopen('http://127.0.0.1:%s/v2/health/ready' % os.environ.get('SDCNET_PORT', '8000'), timeout=4)"]
CMD ["sdc-serve"]
