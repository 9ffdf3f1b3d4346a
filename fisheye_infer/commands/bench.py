"""``fisheye-infer bench MODEL.onnx``: how fast an exported model runs on this machine, stage by stage.

    fisheye-infer bench model.onnx --threads 1,2 --batch 1,2,4 --repeat 10 --out bench.json
    fisheye-infer bench model.fp16.onnx \
        --providers CUDAExecutionProvider,CPUExecutionProvider   # on a GPU (onnxruntime-gpu)

The measurement is ``fisheye_infer.tools.bench`` (end to end and per stage, peak RSS in a fresh
process), the stage split ``fisheye_infer.export.graph_stages``; ``benchmarks/`` compares the figures
with other runtimes.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

from fisheye_infer.commands.common import PROVIDERS_HELP, positive_ints, providers_arg

__all__ = ["configure", "run"]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("model", help="an ONNX file written by fisheye-infer export (fp32, int8 or fp16)")
    parser.add_argument("--providers", type=providers_arg, help=PROVIDERS_HELP)
    parser.add_argument("--threads", type=positive_ints, default=[1, 2], help="intra-op thread counts (default 1,2)")
    parser.add_argument("--batch", type=positive_ints, default=[1, 2, 4], help="batch sizes (default 1,2,4)")
    parser.add_argument("--repeat", type=int, default=10, help="timed calls per setting after warm-up (default 10)")
    parser.add_argument("--warmup", type=int, default=2, help="untimed calls first (default 2)")
    parser.add_argument("--no-stages", action="store_true", help="skip the per-stage split of the graph (needs onnx)")
    parser.add_argument("--no-rss", action="store_true", help="skip the peak-RSS measurement in a fresh process")
    parser.add_argument("--out", help="write the figures as JSON here")
    parser.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from fisheye_infer.errors import ArtifactError
    from fisheye_infer.tools.bench import bench_model, format_table

    if not Path(args.model).is_file():
        raise ArtifactError(f"model {args.model}: no such file")
    stages = None
    if not args.no_stages:
        try:
            from fisheye_infer.export.graph_stages import time_stages
        except ImportError:
            print("bench: no onnx package, skipping the per-stage split (pip install onnx)", file=sys.stderr)
        else:
            stages = time_stages
    result = bench_model(
        args.model,
        args.threads,
        args.batch,
        max(1, args.repeat),
        max(0, args.warmup),
        stages,
        not args.no_rss,
        progress=lambda s: print(s, file=sys.stderr),
        providers=args.providers,
    )
    print(format_table(result))
    if args.out:
        Path(args.out).write_text(json.dumps(result, indent=2))
        print(f"wrote {args.out}")
    return 0
