"""``fisheye-infer serve``: the Detector behind HTTP and WebSocket, under uvicorn or on Ray Serve.

    fisheye-infer serve model.onnx --host 127.0.0.1 --port 8000
    FISHEYE_API_KEY=... FISHEYE_QUEUE_SIZE=16 fisheye-infer serve /models/model.onnx --host 0.0.0.0
    fisheye-infer serve model.onnx --ray --replicas 2 --cpus-per-replica 1 --port 8000
    RAY_ADDRESS=auto fisheye-infer serve /shared/model.onnx --ray --replicas 8 --host 0.0.0.0   # on a running cluster

Every option is also a ``FISHEYE_*`` environment variable (``ServiceSettings``); a flag given
on the command line wins. The API key is read from ``FISHEYE_API_KEY`` only, so it never shows
in a process list. The web stack (and Ray, with ``--ray``) is imported when the command runs, so
the core CLI works without the ``[serve]`` extra and says how to get it.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any

from fisheye_infer.commands.common import NEEDS_RAY_SERVE, NEEDS_SERVE, PROVIDERS_HELP, missing_extra

__all__ = ["configure", "run"]

DESCRIPTION = "Serve a model over HTTP and WebSocket (needs the [serve] extra)."

#: ServiceSettings field -> (type, help) of its flag ``--field-name``; a flag not given leaves the
#: ``FISHEYE_*`` variable or the default in place.
_SETTINGS_FLAGS: dict[str, tuple[type, str]] = {
    "host": (str, "address to listen on (default 127.0.0.1: this machine only)"),
    "port": (int, "port (default 8000)"),
    "threads": (int, "ONNX Runtime intra-op threads (default: all cores)"),
    "providers": (str, PROVIDERS_HELP),
    "workers": (int, "inference threads calling the model (default 1)"),
    "queue_size": (int, "requests waiting before new ones get 503 (default 8)"),
    "max_body_bytes": (int, "largest request body or stream message (default 32 MiB)"),
    "max_batch_frames": (int, "most frames in one /detect/batch request (default 8)"),
    "microbatch_max_size": (
        int,
        "group up to this many concurrent single-frame requests into one run (default 1: off)",
    ),
    "microbatch_max_wait_ms": (float, "how long a request waits for others to group with (default 5)"),
    "request_timeout_s": (float, "longest wait for a result (default 60)"),
    "header_timeout_s": (float, "longest time for a request's headers to arrive (default 10)"),
    "body_timeout_s": (float, "longest time for a request's body to arrive (default 30)"),
    "max_connections": (int, "open connections and requests in progress; beyond, 503 (default 64)"),
    "drain_timeout_s": (float, "on SIGTERM, longest wait for work in flight (default 30)"),
    "cors_origins": (str, "comma-separated browser origins allowed to call the API"),
}


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "model", nargs="?", help="ONNX file written by fisheye-infer export (default: $FISHEYE_MODEL_PATH)"
    )
    for name, (kind, help_text) in _SETTINGS_FLAGS.items():
        parser.add_argument(f"--{name.replace('_', '-')}", type=kind, help=help_text)
    parser.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"))
    _configure_ray(parser)
    parser.set_defaults(run=run)


def _log_to_stderr(level: str) -> None:
    """The service's own messages (ready, draining) beside uvicorn's, in its format."""
    import logging

    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s:     %(message)s"))
    logger = logging.getLogger("fisheye_infer")
    logger.addHandler(handler)
    logger.setLevel(level.upper())


def run(args: argparse.Namespace) -> int:
    try:
        import fastapi  # noqa: F401
        import prometheus_client  # noqa: F401
        import pydantic_settings  # noqa: F401
        import python_multipart  # noqa: F401  (python-multipart)
        import uvicorn  # noqa: F401
    except ImportError as exc:
        return missing_extra(NEEDS_SERVE, exc)
    from pydantic import ValidationError

    from fisheye_infer.runtime.detector import Detector
    from fisheye_infer.service.app import create_app
    from fisheye_infer.service.server import build_server
    from fisheye_infer.service.settings import ServiceSettings

    given = {name: getattr(args, name) for name in _SETTINGS_FLAGS if getattr(args, name) is not None}
    if args.model:
        given["model_path"] = args.model
    try:
        settings = ServiceSettings(**given)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(str(x) for x in e['loc']) or 'settings'}: {e['msg']}" for e in exc.errors())
        print(f"fisheye-infer serve: error: {problems} (flags and FISHEYE_* variables)", file=sys.stderr)
        return 1
    if args.ray:
        return _run_ray(args, settings)
    _log_to_stderr(args.log_level)
    print(f"loading {settings.model_path} ...", file=sys.stderr)
    detector = Detector(
        settings.model_path,
        threads=settings.threads,
        providers=settings.session_providers,
        warmup=settings.warmup,
        spin=settings.spin,
    )
    server = build_server(settings, create_app(settings, detector), log_level=args.log_level)
    server.run()
    return 0 if server.started else 1


def _configure_ray(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("Ray Serve (--ray; needs the [ray] extra)")
    group.add_argument(
        "--ray", action="store_true", help="run the service on Ray Serve: replicas, @serve.batch across callers"
    )
    group.add_argument("--replicas", type=int, default=1, help="replicas, each with its own Detector (default 1)")
    group.add_argument(
        "--cpus-per-replica",
        type=float,
        default=1.0,
        help="CPUs Ray reserves per replica; also its ONNX Runtime threads (default 1)",
    )
    group.add_argument(
        "--max-batch-size", type=int, default=4, help="most frames of concurrent callers run together (default 4)"
    )
    group.add_argument(
        "--batch-wait-ms", type=float, default=10.0, help="how long a frame waits for others to batch with (default 10)"
    )


def _run_ray(args: argparse.Namespace, settings: Any) -> int:
    """Deploy and block until a signal; ``settings`` are the ``ServiceSettings`` the flags built.

    Without ``RAY_ADDRESS`` a local Ray is started on this machine; the command returns after
    SIGINT or SIGTERM, once Ray Serve has shut the application down.
    """
    try:
        import ray
        from ray import serve
    except ImportError as exc:
        return missing_extra(NEEDS_RAY_SERVE, exc)
    from fisheye_infer.errors import ConfigError
    from fisheye_infer.service.ray_serve import RayServeOptions, build_app

    if settings.providers:
        print(
            "fisheye-infer serve: error: providers: the --ray replicas run on CPU "
            "(Ray reserves CPUs for them, not GPUs); serve without --ray on a GPU",
            file=sys.stderr,
        )
        return 1
    try:
        options = RayServeOptions(
            replicas=args.replicas,
            cpus_per_replica=args.cpus_per_replica,
            max_batch_size=args.max_batch_size,
            batch_wait_ms=args.batch_wait_ms,
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    if not settings.model_path.is_file():
        raise ConfigError(f"model {settings.model_path}: no such file")
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    ray.init(include_dashboard=False, configure_logging=False)
    try:
        serve.start(http_options={"host": settings.host, "port": settings.port})
        serve.run(build_app(settings, options), name="fisheye-infer", route_prefix="/")
        print(
            f"serving {settings.model_path} on http://{settings.host}:{settings.port} "
            f"with {options.replicas} replica(s) (Ctrl-C to stop)",
            file=sys.stderr,
        )
        stop.wait()
        print("stopping: Ray Serve drains the replicas", file=sys.stderr)
        serve.shutdown()
    finally:
        ray.shutdown()
    return 0
