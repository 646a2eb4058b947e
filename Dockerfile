# syntax=docker/dockerfile:1.7
# gridplace: REST + gRPC API server (default command) and RQ training worker (`gridplace worker`).
#
#   docker build -t gridplace .                                  # CPU PyTorch (default)
#   docker build --build-arg TORCH_INDEX=https://download.pytorch.org/whl/cu124 -t gridplace:cuda .
#
# Both stages run the same Python image: the venv's interpreter is the build stage's. A CUDA
# build needs no CUDA base image: PyTorch's cu124 wheels bring the CUDA runtime libraries as pip
# packages, and the host's driver comes in through the NVIDIA container runtime (`--gpus all`).
ARG PYTHON_IMAGE=python:3.11-slim-bookworm

FROM ${PYTHON_IMAGE} AS build
ARG TORCH_INDEX=https://download.pytorch.org/whl/cpu
ENV PIP_NO_CACHE_DIR=1 PIP_DISABLE_PIP_VERSION_CHECK=1
RUN apt-get update && apt-get install -y --no-install-recommends gcc g++ && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY pyproject.toml README.md ./
COPY requirements/lock.txt ./requirements/lock.txt
COPY service ./service
RUN python -m venv /opt/gridplace \
 && /opt/gridplace/bin/pip install --upgrade pip \
 && /opt/gridplace/bin/pip install --index-url ${TORCH_INDEX} "torch==2.13.0" \
 && /opt/gridplace/bin/pip install ".[torch]" -c requirements/lock.txt

FROM ${PYTHON_IMAGE} AS runtime
ENV PATH=/opt/gridplace/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    GRIDPLACE_HOST=0.0.0.0 \
    GRIDPLACE_PORT=8080 \
    GRIDPLACE_GRPC_PORT=50051 \
    GRIDPLACE_DATA_DIR=/data
RUN groupadd --system --gid 10001 gridplace \
 && useradd --system --uid 10001 --gid gridplace --home-dir /data --shell /usr/sbin/nologin gridplace \
 && mkdir -p /data && chown gridplace:gridplace /data
COPY --from=build /opt/gridplace /opt/gridplace
USER gridplace
WORKDIR /data
VOLUME ["/data"]
EXPOSE 8080 50051
HEALTHCHECK --interval=15s --timeout=3s --start-period=20s --retries=3 \
  CMD ["python", "-c", "import os, urllib.request; urllib.request.urlopen(f\"http://127.0.0.1:{os.environ.get('GRIDPLACE_PORT', '8080')}/healthz\", timeout=2)"]
ENTRYPOINT ["gridplace"]
CMD ["serve"]
