"""fisheye_infer.service: the Detector behind HTTP and WebSocket (needs the ``[serve]`` extra).

    from fisheye_infer.service import ServiceSettings, create_app
    app = create_app(ServiceSettings(model_path="model.onnx"))

Modules: ``settings`` (ServiceSettings), ``app`` (create_app), ``server`` (uvicorn with a
graceful drain), ``state`` (what one app owns), ``queue`` (bounded inference queue,
micro-batching), ``bodies`` (reading /detect's multipart and JSON bodies), ``intake``
(frame and option checks before decoding, and decoding), ``pipeline``, ``schemas``,
``errors`` (status codes), ``metrics``, ``middleware``, ``openapi``, ``protocol`` (the
``/stream`` frame format, importable without the web stack), ``routers/`` (detect, stream,
health, kserve: the KServe v2 protocol), and ``ray_serve`` (the same app on Ray Serve, the
``[ray]`` extra). The command, ``fisheye-infer serve [--ray]``, is ``fisheye_infer.commands.serve``.

Importing this package loads nothing heavy: the names below are resolved on first use.
"""

from __future__ import annotations

from typing import Any

__all__ = ["ServiceSettings", "create_app", "build_server"]

_WHERE = {"ServiceSettings": "settings", "create_app": "app", "build_server": "server"}


def __getattr__(name: str) -> Any:
    if name in _WHERE:
        from importlib import import_module

        return getattr(import_module(f"fisheye_infer.service.{_WHERE[name]}"), name)
    raise AttributeError(f"module 'fisheye_infer.service' has no attribute {name!r}")
