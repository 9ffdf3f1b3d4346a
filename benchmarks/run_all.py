"""Every benchmark in sequence, each writing its JSON result under ``benchmarks/results/``; then the report.

    python benchmarks/run_all.py                          # every benchmark, at its full size
    python benchmarks/run_all.py --quick                  # their short runs
    python benchmarks/run_all.py --only compare,int8 --model compact

A benchmark runs only where what it needs is here: one that needs a module that is not installed
(OpenVINO, Ray, a CUDA build of ONNX Runtime) or the checkpoint kit is listed as skipped. The ones
that take a model get ``--model``'s files (``model_files``: exported once under
``benchmarks/artifacts/``). A benchmark that fails does not stop the others; the exit status says.
"""

from __future__ import annotations

import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import harness
from model_files import NAMES

BENCHMARKS = Path(__file__).resolve().parent


def _cuda() -> str | None:
    import onnxruntime as ort

    return None if "CUDAExecutionProvider" in ort.get_available_providers() else "no CUDA build of ONNX Runtime here"


def _kit() -> str | None:
    kit = harness.ROOT.parent / "shared" / "checkpoints" / "make_checkpoint.py"
    return None if kit.is_file() else f"no checkpoint kit at {kit}"


@dataclass(frozen=True)
class Step:
    """One benchmark: its arguments for a model (full run, quick run) and what it needs here."""

    script: str
    args: Callable[[str], list[str]] = lambda model: []
    quick: Callable[[str], list[str]] = lambda model: ["--quick"]
    modules: tuple[str, ...] = ()
    check: Callable[[], str | None] = lambda: None

    def skipped(self) -> str | None:
        """Why this benchmark cannot run here, or None."""
        missing = harness.missing(self.modules)
        return f"not installed: {', '.join(missing)}" if missing else self.check()


STEPS = (
    Step("metric_speed"),
    Step("compare", quick=lambda m: ["--quick", "--models", m], modules=("torch", "onnx")),
    Step("int8", modules=("torch", "onnx")),
    Step("model_card", modules=("torch", "onnx")),
    Step("study", modules=("torch", "onnx")),
    Step("train_step", modules=("torch",)),
    Step("spinning", args=lambda m: [m], quick=lambda m: [m, "--quick"]),
    Step("profile_ops", args=lambda m: [m], quick=lambda m: [m, "--runs", "2"], modules=("onnx",)),
    Step("attention_forms", modules=("onnx",)),
    Step("int8_saturation", args=lambda m: [m], quick=lambda m: [m], modules=("torch", "onnx")),
    Step(
        "openvino_isa",
        args=lambda m: [m],
        quick=lambda m: [m, "--threads", "2", "--rounds", "3", "--repeat", "3"],
        modules=("openvino",),
    ),
    Step(
        "load_service", args=lambda m: [m], quick=lambda m: [m, "--quick"], modules=("httpx", "uvicorn", "websockets")
    ),
    Step("scale_out", args=lambda m: [m], quick=lambda m: [m, "--quick"], modules=("ray", "httpx")),
    Step("triton_server", args=lambda m: [m], quick=lambda m: [m, "--quick"], modules=("tritonclient", "pytriton")),
    Step("replay", args=lambda m: [m], quick=lambda m: [m, "--quick"], modules=("rosbags", "mcap")),
    Step("tracking", modules=("torch", "onnx")),
    Step("virtual_cameras", modules=("torch", "onnx")),
    Step("front_ends", modules=("torch", "onnx")),
    Step("speed_table", modules=("torch", "onnx", "openvino")),
    Step(
        "official_configs",
        quick=lambda m: ["--only", "fisheye_bevdet", "nusc_petr"],
        modules=("torch", "onnx"),
        check=_kit,
    ),
    Step(
        "gpu",
        args=lambda m: ["--onnx", m],
        quick=lambda m: ["--onnx", m, "--repeat", "10"],
        modules=("torch",),
        check=_cuda,
    ),
)


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="each benchmark's short run")
    names = [step.script for step in STEPS]
    bench.parser.add_argument("--only", help=f"comma-separated benchmarks, of {', '.join(names)}")
    bench.parser.add_argument("--skip", default="", help="comma-separated benchmarks to leave out")
    bench.parser.add_argument(
        "--model", default="compact", choices=NAMES, help="the model of the benchmarks that take one (default compact)"
    )
    args = bench.parse(argv)
    wanted = args.only.split(",") if args.only else names
    unknown = sorted((set(wanted) | set(filter(None, args.skip.split(",")))) - set(names))
    if unknown:
        bench.parser.error(f"unknown benchmark(s): {', '.join(unknown)}")
    outcome: dict[str, str] = {}
    for step in STEPS:
        if step.script not in wanted or step.script in args.skip.split(","):
            continue
        if reason := step.skipped():
            outcome[step.script] = f"skipped ({reason})"
            continue
        arguments = (step.quick if args.quick else step.args)(args.model)
        command = [sys.executable, f"benchmarks/{step.script}.py", *arguments]
        if args.out_dir != harness.RESULTS:
            command += ["--out-dir", str(args.out_dir)]
        print(f"== {' '.join(command[1:])}", flush=True)
        t0 = time.perf_counter()
        done = subprocess.run(command, cwd=harness.ROOT, check=False)
        took = f"{time.perf_counter() - t0:.0f} s"
        failed = f"FAILED (exit {done.returncode}) after {took}"
        outcome[step.script] = f"done in {took}" if done.returncode == 0 else failed
    if args.out_dir == harness.RESULTS:
        subprocess.run([sys.executable, str(BENCHMARKS / "report.py")], cwd=harness.ROOT, check=False)
    print("\n" + "\n".join(f"{name}: {what}" for name, what in outcome.items()))
    return 1 if any(what.startswith("FAILED") for what in outcome.values()) else 0


if __name__ == "__main__":
    sys.exit(main())
