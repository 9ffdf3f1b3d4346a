"""How fast an exported model runs on this machine, stage by stage (``fisheye-infer bench``).

    result = bench_model("model.onnx", threads=(1, 2),
                         batches=(1, 2, 4))   # fisheye-infer bench model.onnx --out bench.json
    print(format_table(result))

For every thread count and batch size: warm-up, then ``repeat`` timed calls of
``Detector.detect_batch`` on PNG-encoded synthetic renders of the model's own rig, split into
decode (PNG bytes -> arrays), preprocessing, inference and post-processing, with median and
p90 of each and the throughput. Given a ``StageTimer`` (``fisheye_infer.export.graph_stages.time_stages``,
which needs ``onnx``), inference is further split into backbone+neck, view transform and head by
running the graph cut into stage models. Peak RSS is measured in a fresh process per thread count,
as a service would see it.
``providers`` runs all of it in other ONNX Runtime execution providers (a GPU's: ``CUDAExecutionProvider``);
thread counts then only set the CPU side (nodes the provider leaves to the CPU, and the stage cuts' copies).
Nothing here asserts a speed: the numbers are for people; ``benchmarks/compare.py`` sets them
beside PyTorch, OpenVINO and the machine's GEMM throughput.
"""

from __future__ import annotations

import json
import os
import platform
import resource
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from fisheye_infer.runtime.session import Provider
from fisheye_infer.tools.cpu import cpu_info

__all__ = ["StageTimer", "bench_model", "format_table", "png_frame", "stats", "peak_rss_mb"]

#: Times an exported file's stages: ``(path, feeds, session_options_factory, repeat=, providers=)`` ->
#: milliseconds per stage and repeat; ``fisheye_infer.export.graph_stages.time_stages`` is one.
StageTimer = Callable[..., dict[str, list[float]]]


def stats(values: Sequence[float]) -> dict[str, float]:
    """Median and p90 (ms): the median is robust to a neighbour's load spikes, p90 shows them."""
    a = np.asarray(values, np.float64)
    return {"median": float(np.median(a)), "p90": float(np.percentile(a, 90)), "n": int(len(a))}


def png_frame(model_path: str | Path, seed: int = 0) -> dict[str, bytes]:
    """One synthetic render of the model's rig, each camera encoded as PNG (what a client sends)."""
    from fisheye_infer.runtime.artifact import read_meta
    from fisheye_infer.scenes.render import Renderer, random_scene

    rig = read_meta(model_path).rig
    frame = Renderer(texture_seed=seed).render(rig, random_scene(np.random.default_rng(seed)))
    return {name: cv2.imencode(".png", image)[1].tobytes() for name, image in frame.items()}


def _e2e(detector: Any, frames: list[dict[str, bytes]], repeat: int, warmup: int) -> dict[str, Any]:
    parts: dict[str, list[float]] = {"decode": [], "preprocess": [], "inference": [], "postprocess": [], "total": []}
    for i in range(warmup + repeat):
        t0 = time.perf_counter()
        results = detector.detect_batch(frames)
        total = (time.perf_counter() - t0) * 1e3
        if i < warmup:
            continue
        for key in ("decode", "preprocess", "inference", "postprocess"):
            parts[key].append(results[0].timings_ms[key])
        parts["total"].append(total)
    out: dict[str, Any] = {k: stats(v) for k, v in parts.items()}
    out["fps"] = len(frames) * 1e3 / out["total"]["median"]
    return out


def _graph_stages(
    time_stages: StageTimer,
    path: Path,
    frame: dict[str, bytes],
    detector: Any,
    threads: int,
    repeat: int,
    providers: list[Provider],
) -> dict[str, Any]:
    from fisheye_infer.runtime.preprocess import load_frame, stack_frames
    from fisheye_infer.runtime.session import session_options

    images, valid = stack_frames(
        [load_frame(frame, detector.info.cameras, detector.info.image_size, detector.info.camera_sizes)],
        detector.info.image_size,
    )
    times = time_stages(
        path,
        {"images": images, "camera_valid": valid},
        lambda: session_options(threads),
        repeat=repeat,
        providers=providers,
    )
    return {k: stats(v) for k, v in times.items()}


def peak_rss_mb(
    model_path: str | Path, threads: int, runs: int = 3, providers: Sequence[Provider] = ("CPUExecutionProvider",)
) -> float:
    """Peak RSS (MB, host memory) of a fresh process that loads a Detector and runs ``runs`` frames."""
    cmd = [
        sys.executable,
        "-m",
        "fisheye_infer.tools.bench",
        "--rss-child",
        str(model_path),
        str(threads),
        str(runs),
        json.dumps(list(providers)),
    ]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False)
    if done.returncode != 0:
        raise RuntimeError(f"peak RSS measurement failed: {done.stderr.strip()[-500:]}")
    return float(done.stdout.strip().splitlines()[-1])


def _rss_child(model_path: str, threads: int, runs: int, providers: str) -> None:
    from fisheye_infer.runtime.detector import Detector

    frame = png_frame(model_path)
    detector = Detector(
        model_path, threads=threads, providers=[p if isinstance(p, str) else tuple(p) for p in json.loads(providers)]
    )
    for _ in range(runs):
        detector.detect(frame)
    print(_own_peak_rss_mb())


def _own_peak_rss_mb() -> float:
    """This process's peak RSS. Linux: ``VmHWM``, which starts afresh at exec; ``ru_maxrss`` would
    report the parent's peak instead when the parent was larger (it survives fork and exec)."""
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1]) / 1024  # kB
    except OSError:
        pass
    scale = 1024 * 1024 if sys.platform == "darwin" else 1024  # bytes on macOS, KiB on Linux
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / scale


def machine() -> dict[str, Any]:
    import onnxruntime as ort

    cpu = cpu_info()
    return {
        "cpu": cpu.label,
        "cpu_count": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "onnxruntime": ort.__version__,
        "avx512": cpu.avx512,
        "vnni": cpu.vnni,
        "avx2": cpu.avx2,
        "gpus": _nvidia_gpus(),
    }


def _nvidia_gpus() -> list[str]:
    """The NVIDIA GPUs' names and drivers as ``nvidia-smi`` lists them; none without it."""
    try:
        done = subprocess.run(
            ["nvidia-smi", "--query-gpu=name,driver_version", "--format=csv,noheader"],
            capture_output=True,
            text=True,
            timeout=10,
            check=False,
        )
    except (OSError, subprocess.TimeoutExpired):
        return []
    return [line.strip() for line in done.stdout.splitlines() if line.strip()] if done.returncode == 0 else []


def bench_model(
    path: str | Path,
    threads: Sequence[int] = (1, 2),
    batches: Sequence[int] = (1, 2, 4),
    repeat: int = 10,
    warmup: int = 2,
    stages: StageTimer | None = None,
    rss: bool = True,
    progress: Any = print,
    providers: str | Sequence[Provider] | None = None,
) -> dict[str, Any]:
    """Everything ``fisheye-infer bench`` measures for one model, as a JSON-ready dict.

    For every thread count and batch size: ``warmup`` untimed calls, then ``repeat`` timed calls of
    ``Detector.detect_batch`` on PNG-encoded synthetic renders of the model's own rig, split into decode,
    preprocessing, inference and post-processing. Nothing is asserted: the numbers are for people.

    Args:
        path (str | Path): The exported ONNX file.
        threads (Sequence[int]): ONNX Runtime intra-op thread counts to measure.
        batches (Sequence[int]): Batch sizes to measure (frames per ``detect_batch`` call).
        repeat (int): Timed calls per (threads, batch).
        warmup (int): Untimed calls before them.
        stages (StageTimer | None): Also time the graph's stages (backbone and neck, view transform, head) with
            this function (``fisheye_infer.export.graph_stages.time_stages``, which needs ``onnx``).
        rss (bool): Measure the peak resident memory of a fresh process per thread count.
        progress (Any): Called with a line of text before each measurement (default: ``print``).
        providers (str | Sequence[Provider] | None): ONNX Runtime execution providers, as
            [`Detector`][fisheye_infer.runtime.detector.Detector] takes them (None: the CPU; ``"auto"``); thread
            counts then only set the CPU side.

    Returns:
        dict[str, Any]: ``model``, ``machine`` (CPU, platform, versions, GPUs), ``providers`` (those the session
            really got), ``model_id``, ``architecture``, ``quantization``, ``runs`` (per threads and batch: median,
            p90 and count of each stage in ms, and ``fps``), ``stages`` and ``peak_rss_mb`` per thread count.

    Raises:
        ArtifactError: The file is missing or not an exported model.
        RuntimeError: The peak memory measurement's process failed.

    Examples:
        ```python
        result = bench_model("model.onnx", threads=(1, 2), batches=(1, 2, 4))
        print(format_table(result))
        json.dump(result, open("bench.json", "w"))
        ```
    """
    from fisheye_infer.runtime.detector import Detector
    from fisheye_infer.runtime.session import provider_name, resolve_providers

    path = Path(path)
    frame = png_frame(path)
    asked = resolve_providers(providers)
    result: dict[str, Any] = {
        "model": str(path),
        "machine": machine(),
        "providers": [provider_name(p) for p in asked],
        "repeat": repeat,
        "warmup": warmup,
        "runs": [],
        "stages": {},
        "peak_rss_mb": {},
    }
    for t in threads:
        detector = Detector(path, threads=t, providers=providers)
        result["providers"] = list(detector.info.providers)
        chosen: list[Provider] = list(detector.info.providers) if providers == "auto" else asked  # what "auto" started
        result["model_id"] = detector.info.model_id
        result["architecture"] = detector.info.architecture
        result["quantization"] = detector.info.meta.quantization.mode if detector.info.meta.quantization else "fp32"
        for b in batches:
            progress(f"bench {path.name}: {t} thread(s), batch {b}")
            result["runs"].append({"threads": t, "batch": b, **_e2e(detector, [frame] * b, repeat, warmup)})
        if stages:
            progress(f"bench {path.name}: {t} thread(s), graph stages")
            result["stages"][str(t)] = _graph_stages(stages, path, frame, detector, t, max(3, repeat // 2), chosen)
        del detector
        if rss:
            result["peak_rss_mb"][str(t)] = peak_rss_mb(path, t, providers=chosen)
    return result


def format_table(result: dict[str, Any]) -> str:
    """A plain-text table of a benchmark's result.

    Args:
        result (dict[str, Any]): What [`bench_model`][fisheye_infer.tools.bench.bench_model] returned.

    Returns:
        str: One line per (threads, batch) with the median and p90 total and each stage's median in ms and the
            frames per second; then the graph stages and the peak memory, where measured.
    """
    lines = [
        f"{result['model']} ({result.get('architecture')}, {result.get('quantization')}; "
        f"{', '.join(result.get('providers', ['CPUExecutionProvider']))})",
        "threads batch | total med/p90 ms | decode | preprocess | inference | postprocess | frames/s",
    ]
    for r in result["runs"]:
        lines.append(
            f"{r['threads']:>7} {r['batch']:>5} | {r['total']['median']:8.1f} / {r['total']['p90']:7.1f} | "
            f"{r['decode']['median']:6.1f} | {r['preprocess']['median']:10.1f} | {r['inference']['median']:9.1f} | "
            f"{r['postprocess']['median']:11.2f} | {r['fps']:8.2f}"
        )
    for t, st in result["stages"].items():
        parts = ", ".join(f"{k} {v['median']:.1f} (p90 {v['p90']:.1f})" for k, v in st.items())
        lines.append(f"graph stages at {t} thread(s), batch 1, ms: {parts}")
    for t, mb in result["peak_rss_mb"].items():
        lines.append(f"peak RSS at {t} thread(s): {mb:.0f} MB")
    return "\n".join(lines)


if __name__ == "__main__":
    if len(sys.argv) == 6 and sys.argv[1] == "--rss-child":
        _rss_child(sys.argv[2], int(sys.argv[3]), int(sys.argv[4]), sys.argv[5])
    else:
        from fisheye_infer.cli import main

        sys.exit(main(["bench", *sys.argv[1:]]))
