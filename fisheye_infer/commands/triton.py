"""``fisheye-infer triton``: write a Triton model repository for an exported file.

    fisheye-infer triton model.onnx --out model_repository [--name NAME] [--max-batch-size 4]
                         [--instances 1] [--kind auto|cpu|gpu] [--tensorrt [--tensorrt-precision FP16]]

Needs only the core install: the repository is written from the file with ONNX Runtime.
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
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fisheye_infer.deploy.triton.repository import TritonOptions, write_repository
    from fisheye_infer.errors import ConfigError

    try:
        options = TritonOptions(
            name=args.name,
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
    print("next: start Triton on the repository (see the README, 'Scale out'):")
    print(
        f"  docker run --rm -p 8000:8000 -v {Path(args.out).resolve()}:/models nvcr.io/nvidia/tritonserver:<yy.mm>-py3 "
        "tritonserver --model-repository=/models"
    )
    print(
        '  python -c "from fisheye_infer.deploy.triton import TritonDetector; '
        f"print(TritonDetector('127.0.0.1:8000', '{target.name}').info)\""
    )
    return 0
