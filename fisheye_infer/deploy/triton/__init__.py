"""fisheye_infer.deploy.triton: the exported file behind NVIDIA Triton Inference Server.

    fisheye-infer triton model.onnx --out model_repository        # DIR/<name>/config.pbtxt + DIR/<name>/1/model.onnx
    tritonserver --model-repository=model_repository

    from fisheye_infer.deploy.triton import TritonDetector
    detector = TritonDetector("127.0.0.1:8000", "fisheye_bevdet")   # the same detect() as Detector

Modules: ``repository`` (the model repository and its ``config.pbtxt``; core only),
``client`` (``TritonDetector`` over the KServe v2 HTTP protocol; needs the ``[triton]`` extra),
``commands`` (the CLI). Importing this package loads neither tritonclient nor protobuf.
"""

from __future__ import annotations

from typing import Any

__all__ = ["TritonDetector", "TritonOptions", "model_config", "render_pbtxt", "write_repository", "model_name"]

_WHERE = {
    "TritonDetector": "client",
    "TritonOptions": "repository",
    "model_config": "repository",
    "render_pbtxt": "repository",
    "write_repository": "repository",
    "model_name": "repository",
}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        from importlib import import_module

        return getattr(import_module(f"fisheye_infer.deploy.triton.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'fisheye_infer.deploy.triton' has no attribute {name!r}")
