"""``fisheye-infer serve --ray``: the service on Ray Serve (flags and the blocking runner).

    fisheye-infer serve model.onnx --ray --replicas 2 --cpus-per-replica 1 --port 8000
    RAY_ADDRESS=auto fisheye-infer serve /shared/model.onnx --ray --replicas 8 --host 0.0.0.0   # on a running cluster

Without ``RAY_ADDRESS`` a local Ray is started on this machine. The command returns after
SIGINT or SIGTERM, once Ray Serve has shut the application down. Ray is imported only here,
so ``fisheye-infer serve`` without ``--ray`` works without the ``[ray]`` extra.
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
from typing import Any

__all__ = ["configure_ray_serve", "run_ray_serve", "NEEDS_RAY"]

NEEDS_RAY = "fisheye-infer serve --ray needs the ray extra: pip install 'fisheye-infer[ray]'"


def configure_ray_serve(parser: argparse.ArgumentParser) -> None:
    group = parser.add_argument_group("Ray Serve (--ray; needs the [ray] extra)")
    group.add_argument("--ray", action="store_true", help="run the service on Ray Serve: replicas, @serve.batch across callers")
    group.add_argument("--replicas", type=int, default=1, help="replicas, each with its own Detector (default 1)")
    group.add_argument("--cpus-per-replica", type=float, default=1.0, help="CPUs Ray reserves per replica; also its ONNX Runtime threads (default 1)")
    group.add_argument("--max-batch-size", type=int, default=4, help="most frames of concurrent callers run together (default 4)")
    group.add_argument("--batch-wait-ms", type=float, default=10.0, help="how long a frame waits for others to batch with (default 10)")


def run_ray_serve(args: argparse.Namespace, settings: Any) -> int:
    """Deploy and block until a signal; ``settings`` are the ``ServiceSettings`` the flags built."""
    try:
        import ray
        from ray import serve
    except ImportError as exc:
        print(f"{NEEDS_RAY} ({exc})", file=sys.stderr)
        return 1
    from fisheye_infer.errors import ConfigError
    from fisheye_infer.service.ray_serve import RayServeOptions, build_app

    try:
        options = RayServeOptions(replicas=args.replicas, cpus_per_replica=args.cpus_per_replica, max_batch_size=args.max_batch_size, batch_wait_ms=args.batch_wait_ms)
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
        print(f"serving {settings.model_path} on http://{settings.host}:{settings.port} with {options.replicas} replica(s) "
              f"(Ctrl-C to stop)", file=sys.stderr)
        stop.wait()
        print("stopping: Ray Serve drains the replicas", file=sys.stderr)
        serve.shutdown()
    finally:
        ray.shutdown()
    return 0
