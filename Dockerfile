# fisheye-infer service image: the torch-free runtime and the [serve] extra, run as a non-root user.
#
#   docker build -t fisheye-infer .
#   docker run --rm -p 8000:8000 -v "$PWD/model.onnx:/models/model.onnx:ro" fisheye-infer
#   curl localhost:8000/readyz
#
# The model is not baked in: mount (or COPY in a derived image) an ONNX file written by
# `fisheye-infer export` at /models/model.onnx. Every setting is a FISHEYE_* variable
# (see service/settings.py), e.g. -e FISHEYE_API_KEY=... -e FISHEYE_THREADS=4
# -e FISHEYE_QUEUE_SIZE=16. Set FISHEYE_THREADS to the container's CPU limit: ONNX Runtime
# otherwise sizes its pool by the host's cores.
#
# Shutdown: `docker stop` sends SIGTERM to the server (PID 1, exec form below), which stops
# taking new work (503) and finishes what is in flight within FISHEYE_DRAIN_TIMEOUT_S. That is
# 8 s here, inside docker's default 10 s grace period; raise both together (docker stop -t N).
#
# tests/service/test_install.py repeats the COPY and pip steps below in a fresh virtual
# environment and checks that torch stays out; keep the two in step.
FROM python:3.11-slim

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1

RUN useradd --create-home --uid 10001 fisheye

WORKDIR /opt/fisheye-infer
COPY pyproject.toml README.md LICENSE ./
COPY fisheye_infer ./fisheye_infer
COPY models ./models
COPY export ./export
COPY service ./service
# models/ and export/ are parts of the one installed namespace; they import torch only when used.
RUN pip install '.[serve]' \
 && ! python -c "import torch" 2>/dev/null \
 && fisheye-infer serve --help > /dev/null

ENV FISHEYE_MODEL_PATH=/models/model.onnx \
    FISHEYE_HOST=0.0.0.0 \
    FISHEYE_PORT=8000 \
    FISHEYE_DRAIN_TIMEOUT_S=8

USER fisheye
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s --retries=3 \
  CMD python -c "import os, urllib.request; urllib.request.urlopen('http://127.0.0.1:%s/healthz' % os.environ.get('FISHEYE_PORT', '8000'), timeout=3)"
STOPSIGNAL SIGTERM
CMD ["fisheye-infer", "serve"]
