# Runtime image: the core package and the [serve] extra, no torch.
# The model file is mounted (or copied) at /models/model.onnx.
FROM python:3.11-slim

ENV PIP_NO_CACHE_DIR=1 PYTHONDONTWRITEBYTECODE=1 PYTHONUNBUFFERED=1
RUN useradd --create-home --uid 10001 fisheye
WORKDIR /opt/fisheye-infer
COPY pyproject.toml README.md ./
COPY fisheye_infer ./fisheye_infer
COPY models ./models
COPY export ./export
COPY service ./service
RUN pip install '.[serve]'

USER fisheye
EXPOSE 8000
HEALTHCHECK --interval=30s --timeout=5s --start-period=60s \
  CMD python -c "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/healthz', timeout=3)"
CMD ["fisheye-infer", "serve", "/models/model.onnx", "--host", "0.0.0.0", "--port", "8000"]
