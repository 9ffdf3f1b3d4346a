"""``fisheye-infer triton``: write a Triton model repository for an exported file.

    fisheye-infer triton model.onnx --out model_repository [--name NAME] [--max-batch-size 4]
                         [--instances 1] [--kind auto|cpu|gpu] [--tensorrt [--tensorrt-precision FP16]]
    fisheye-infer triton model.onnx --out model_repository --backend python [--serve [--http-port 8000]]

Needs only the core install: the repository is written from the file with ONNX Runtime. ``--serve`` starts the
``tritonserver`` that the ``nvidia-pytriton`` wheel bundles on the repository (127.0.0.1) until interrupted.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from fisheye_infer.commands.common import int_list

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="ONNX file written by fisheye-infer export")
    parser.add_argument(
        "--out", required=True, help="model repository folder (created; other models in it are left alone)"
    )
    parser.add_argument("--name", help="model name (default: the file's stem)")
    parser.add_argument(
        "--backend",
        choices=("onnxruntime", "python"),
        default="onnxruntime",
        help="Triton's ONNX Runtime backend (default), or its Python backend running fisheye-infer's session (CPU)",
    )
    parser.add_argument(
        "--max-batch-size", type=int, default=4, help="frames per batched run; 0 turns batching off (default 4)"
    )
    parser.add_argument(
        "--max-queue-delay-us", type=int, default=5000, help="dynamic batching: wait for more requests (default 5000)"
    )
    parser.add_argument("--preferred-batch-sizes", type=int_list, default=(), help="dynamic batching: e.g. 2,4")
    parser.add_argument("--instances", type=int, default=1, help="model instances per device (default 1)")
    parser.add_argument(
        "--kind",
        choices=("auto", "cpu", "gpu"),
        default="auto",
        help="where instances run (default auto: GPU when present)",
    )
    parser.add_argument("--gpus", type=int_list, default=(), help="GPU ids for --kind gpu, e.g. 0,1")
    parser.add_argument("--threads", type=int, help="ONNX Runtime intra-op threads per instance")
    parser.add_argument(
        "--tensorrt", action="store_true", help="TensorRT as the GPU execution accelerator (needs --kind gpu)"
    )
    parser.add_argument("--tensorrt-precision", choices=("FP32", "FP16"), default="FP16")
    parser.add_argument("--tensorrt-workspace-bytes", type=int, default=1 << 30)
    parser.add_argument("--tensorrt-cache", help="folder (inside the server) where TensorRT engines are cached")
    parser.add_argument("--force", action="store_true", help="replace an existing model folder of the same name")
    parser.add_argument(
        "--serve",
        action="store_true",
        help="then serve the repository with the bundled tritonserver on 127.0.0.1 until interrupted "
        "(--backend python; pip install --no-deps nvidia-pytriton==0.7.0)",
    )
    parser.add_argument("--http-port", type=int, default=8000, help="--serve: HTTP port (default 8000)")
    parser.add_argument("--grpc-port", type=int, default=8001, help="--serve: gRPC port (default 8001)")
    parser.set_defaults(run=run)


def serve(repository: Path, http_port: int, grpc_port: int) -> int:
    """Serve ``repository`` with the bundled tritonserver until interrupted.

    Args:
        repository: The model repository.
        http_port: The HTTP port on 127.0.0.1.
        grpc_port: The gRPC port on 127.0.0.1.

    Returns:
        int: The exit code (0 after an interrupt).
    """
    import signal
    import threading

    from fisheye_infer.deploy.triton.server import TritonServer

    stop = threading.Event()
    for number in (signal.SIGINT, signal.SIGTERM):
        signal.signal(number, lambda *_: stop.set())
    with TritonServer(repository, http_port=http_port, grpc_port=grpc_port) as server:
        print(f"serving {repository} at http://{server.http_url} and grpc {server.grpc_url} (Ctrl-C stops)", flush=True)
        while not stop.wait(1.0):
            if server.process is not None and server.process.poll() is not None:
                print(f"tritonserver exited with code {server.process.returncode}:\n{server.log_tail()}")
                return 1
    return 0


def run(args: argparse.Namespace) -> int:
    from fisheye_infer.deploy.triton.repository import TritonOptions, write_repository
    from fisheye_infer.errors import ConfigError

    try:
        if args.serve and args.backend != "python":
            raise ValueError("--serve: the bundled tritonserver has no ONNX Runtime backend; add --backend python")
        options = TritonOptions(
            name=args.name,
            backend=args.backend,
            max_batch_size=args.max_batch_size,
            max_queue_delay_us=args.max_queue_delay_us,
            preferred_batch_sizes=args.preferred_batch_sizes,
            instances=args.instances,
            kind=args.kind,
            gpus=args.gpus,
            threads=args.threads,
            tensorrt=args.tensorrt,
            tensorrt_precision=args.tensorrt_precision,
            tensorrt_workspace_bytes=args.tensorrt_workspace_bytes,
            tensorrt_cache=args.tensorrt_cache,
        )
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    target = write_repository(args.model, args.out, options, force=args.force)
    print(f"wrote {target / 'config.pbtxt'} and {target / '1' / 'model.onnx'}")
    if args.serve:
        return serve(Path(args.out), args.http_port, args.grpc_port)
    print("next: start Triton on the repository (see the README, 'Scale out'):")
    if args.backend == "python":
        print(f"  fisheye-infer triton {args.model} --out {args.out} --backend python --force --serve")
    else:
        print(
            f"  docker run --rm -p 8000:8000 -v {Path(args.out).resolve()}:/models "
            "nvcr.io/nvidia/tritonserver:<yy.mm>-py3 tritonserver --model-repository=/models"
        )
    print(
        '  python -c "from fisheye_infer.deploy.triton import TritonDetector; '
        f"print(TritonDetector('127.0.0.1:8000', '{target.name}').info)\""
    )
    return 0
