"""``fisheye-infer serve``: the Detector behind HTTP and WebSocket, under uvicorn.

    fisheye-infer serve model.onnx --host 127.0.0.1 --port 8000
    FISHEYE_API_KEY=... FISHEYE_QUEUE_SIZE=16 fisheye-infer serve /models/model.onnx --host 0.0.0.0

Every option is also a ``FISHEYE_*`` environment variable (``ServiceSettings``); a flag given
on the command line wins. The API key is read from ``FISHEYE_API_KEY`` only, so it never shows
in a process list. The web stack is imported when the command runs, so the core CLI works
without the ``[serve]`` extra and says how to get it.
"""

from __future__ import annotations

import argparse
import sys

from fisheye_infer.service.ray_commands import configure_ray_serve, run_ray_serve

__all__ = ["configure_serve", "run_serve"]

NEEDS_SERVE = "fisheye-infer serve needs the serve extra: pip install 'fisheye-infer[serve]'"

# flag -> ServiceSettings field (None: not given, the environment or the default applies)
_FLAGS = ("host", "port", "threads", "workers", "queue_size", "max_body_bytes", "max_batch_frames",
          "microbatch_max_size", "microbatch_max_wait_ms", "request_timeout_s", "header_timeout_s", "body_timeout_s",
          "max_connections", "drain_timeout_s", "cors_origins")


def configure_serve(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", nargs="?", help="ONNX file written by fisheye-infer export (default: $FISHEYE_MODEL_PATH)")
    parser.add_argument("--host", help="address to listen on (default 127.0.0.1: this machine only)")
    parser.add_argument("--port", type=int, help="port (default 8000)")
    parser.add_argument("--threads", type=int, help="ONNX Runtime intra-op threads (default: all cores)")
    parser.add_argument("--workers", type=int, help="inference threads calling the model (default 1)")
    parser.add_argument("--queue-size", type=int, help="requests waiting before new ones get 503 (default 8)")
    parser.add_argument("--max-body-bytes", type=int, help="largest request body or stream message (default 32 MiB)")
    parser.add_argument("--max-batch-frames", type=int, help="most frames in one /detect/batch request (default 8)")
    parser.add_argument("--microbatch-max-size", type=int, help="group up to this many concurrent single-frame requests into one run (default 1: off)")
    parser.add_argument("--microbatch-max-wait-ms", type=float, help="how long a request waits for others to group with (default 5)")
    parser.add_argument("--request-timeout-s", type=float, help="longest wait for a result (default 60)")
    parser.add_argument("--header-timeout-s", type=float, help="longest time for a request's headers to arrive (default 10)")
    parser.add_argument("--body-timeout-s", type=float, help="longest time for a request's body to arrive (default 30)")
    parser.add_argument("--max-connections", type=int, help="open connections and requests in progress; beyond, 503 (default 64)")
    parser.add_argument("--drain-timeout-s", type=float, help="on SIGTERM, longest wait for work in flight (default 30)")
    parser.add_argument("--cors-origins", help="comma-separated browser origins allowed to call the API")
    parser.add_argument("--log-level", default="info", choices=("critical", "error", "warning", "info", "debug"))
    configure_ray_serve(parser)
    parser.set_defaults(run=run_serve)


def _log_to_stderr(level: str) -> None:
    """The service's own messages (ready, draining) beside uvicorn's, in its format."""
    import logging

    handler = logging.StreamHandler()
    handler.setFormatter(logging.Formatter("%(levelname)s:     %(message)s"))
    logger = logging.getLogger("fisheye_infer")
    logger.addHandler(handler)
    logger.setLevel(level.upper())


def run_serve(args: argparse.Namespace) -> int:
    try:
        import fastapi  # noqa: F401
        import multipart  # noqa: F401  (python-multipart)
        import prometheus_client  # noqa: F401
        import pydantic_settings  # noqa: F401
        import uvicorn  # noqa: F401
    except ImportError as exc:
        print(f"{NEEDS_SERVE} ({exc})", file=sys.stderr)
        return 1
    from pydantic import ValidationError

    from fisheye_infer.detector import Detector
    from fisheye_infer.service.app import create_app
    from fisheye_infer.service.server import build_server
    from fisheye_infer.service.settings import ServiceSettings

    given = {name: getattr(args, name) for name in _FLAGS if getattr(args, name) is not None}
    if args.model:
        given["model_path"] = args.model
    try:
        settings = ServiceSettings(**given)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(str(x) for x in e['loc']) or 'settings'}: {e['msg']}" for e in exc.errors())
        print(f"fisheye-infer serve: error: {problems} (flags and FISHEYE_* variables)", file=sys.stderr)
        return 1
    if args.ray:
        return run_ray_serve(args, settings)
    _log_to_stderr(args.log_level)
    print(f"loading {settings.model_path} ...", file=sys.stderr)
    detector = Detector(settings.model_path, threads=settings.threads, warmup=settings.warmup)
    server = build_server(settings, create_app(settings, detector), log_level=args.log_level)
    server.run()
    return 0 if server.started else 1
