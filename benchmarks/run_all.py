"""Build, export and benchmark both detectors on this machine; print one table and the issue's targets.

    .venv/bin/python benchmarks/run_all.py                  # everything, about 15-25 min on 2 cores
    .venv/bin/python benchmarks/run_all.py --repeat 3 --no-compile --models fisheye-bevdet

Seeded checkpoints (seed 0) and their fp32 and int8 exports go to ``benchmarks/artifacts/``
(gitignored; reused when present). Then, per model: ``fisheye_infer.bench.bench_model`` (latency
per stage, throughput at batch 1/2/4, peak RSS at 1 and 2 threads), and, in this one process,
in turns, a few calls at a time: ORT fp32 and int8, OpenVINO on the same fp32 file, PyTorch eager
(plus torch.compile in a child process). GEMM throughput and graph FLOPs give the machine's limit. Figures go to
``benchmarks/artifacts/results.json``. Not part of the tests: nothing here asserts a speed.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import cv2
import numpy as np

sys.path.insert(0, str(Path(__file__).parent))
from compare import count_flops, gemm_peak, openvino, service_overhead, timed, torch_compile  # noqa: E402

ART = Path(__file__).parent / "artifacts"
TARGETS = {"fisheye-bevdet": 2.3, "fisheye-petr": 1.8}


def build(arch: str, progress: Callable[[str], None]) -> tuple[Path, Path, Path]:
    from fisheye_infer.export.exporter import export, export_int8
    from fisheye_infer.models import make_checkpoint

    ART.mkdir(exist_ok=True)
    ckpt, fp32, int8 = ART / f"{arch}.pth", ART / f"{arch}.onnx", ART / f"{arch}.int8.onnx"
    if not ckpt.exists():
        make_checkpoint(arch, seed=0, path=ckpt)
    if not fp32.exists():
        export(ckpt, fp32, progress=progress)
    if not int8.exists():
        export_int8(fp32, int8, force=True, progress=progress)  # seeded weights: kept whatever the box match
    return ckpt, fp32, int8


def alternate(fns: dict[str, Callable[[], object]], rounds: int, block: int = 3) -> dict[str, float]:
    """Median ms of each function, run in turns so load spikes hit all alike: each round calls every
    function once untimed, then ``block`` times timed. The untimed call takes what the function
    before it left behind: ONNX Runtime's and PyTorch's worker threads spin for a while after a call
    and take CPU from whatever runs next (30-40 ms on 2 cores), which is the previous runtime's cost,
    not this one's."""
    times: dict[str, list[float]] = {k: [] for k in fns}
    for _ in range(rounds):
        for k, fn in fns.items():
            times[k] += timed(fn, block, warmup=1)
    return {k: float(np.median(v)) for k, v in times.items()}


def measure(arch: str, args: argparse.Namespace) -> dict[str, Any]:
    import torch

    from fisheye_infer.artifact import read_meta
    from fisheye_infer.bench import bench_model
    from fisheye_infer.detector import Detector
    from fisheye_infer.export.exporter import verification_frames

    progress = lambda s: print(s, file=sys.stderr, flush=True)  # noqa: E731
    ckpt, fp32, int8 = build(arch, progress)
    t = args.ratio_threads
    out: dict[str, Any] = {"arch": arch, "fp32": str(fp32), "int8": str(int8)}
    out["bench_fp32"] = bench_model(fp32, args.threads, args.batch, args.repeat, 1, progress=progress)
    out["bench_int8"] = bench_model(int8, args.threads, [1], args.repeat, 1, stages=False, progress=progress)
    meta = read_meta(fp32)
    images = verification_frames(meta.rig, 1)
    valid = np.ones(images.shape[:2], bool)
    frame = list(images[0])
    ort32, ort8 = Detector(fp32, threads=t), Detector(int8, threads=t)
    torch.set_num_threads(t)
    from compare import load_torch_model

    model = load_torch_model(arch, ckpt)
    xt, vt = torch.from_numpy(images), torch.from_numpy(valid)

    def eager() -> None:
        with torch.inference_mode():
            model(xt, vt)

    fns = {"ort_fp32_e2e": lambda: ort32.detect(frame), "ort_int8_e2e": lambda: ort8.detect(frame),
           "ort_fp32_run": lambda: ort32.run_arrays(images, valid), "torch_eager": eager}
    ov = openvino(fp32, images, t)
    if callable(ov):
        fns["openvino"] = ov
    out["openvino"] = {} if callable(ov) else {"error": ov}
    progress(f"{arch}: alternating {', '.join(fns)} at {t} thread(s)")
    out["alternating_ms"] = alternate(fns, args.repeat)
    if args.compile:
        progress(f"{arch}: torch.compile (child process)")
        out["torch_compile"] = torch_compile(arch, ckpt, t, args.repeat)
    else:
        out["torch_compile"] = {"error": "skipped (--no-compile)"}
    out["flops_g"] = count_flops(fp32)
    out["int8_parity"] = read_meta(int8).parity.model_dump()
    jpeg = {name: cv2.imencode(".jpg", image, [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes() for name, image in zip(meta.cameras, frame)}
    out["service"] = service_overhead(fp32, jpeg, frame, t, args.repeat) if args.service else {"error": "skipped (--no-service)"}
    return out


def _ratio(a: float | None, b: float | None) -> float | None:
    return None if not a or not b else a / b


def report(results: dict[str, Any]) -> str:
    gemm = results["gemm_gflops"]
    lines = [f"GEMM 2048^2 at {results['ratio_threads']} thread(s), GFLOP/s: " + ", ".join(f"{k} {v:.0f}" for k, v in gemm.items())]
    lines.append("| model | FLOPs G | ORT fp32 ms | int8 ms | eager ms | compile ms | OpenVINO ms | view share | FLOP-bound ms | RSS MB |")
    lines.append("|---|---|---|---|---|---|---|---|---|---|")
    targets = []
    for arch, r in results["models"].items():
        alt = r["alternating_ms"]
        fp32, int8, eager = alt["ort_fp32_run"], alt["ort_int8_e2e"], alt["torch_eager"]
        comp = r["torch_compile"].get("ms")
        comp_ms = float(np.median(comp)) if comp else None
        ov_ms = alt.get("openvino")
        st = r["bench_fp32"]["stages"].get(str(results["ratio_threads"]), {})
        total_stages = sum(v["median"] for v in st.values()) or None
        share = _ratio(st.get("view_transform", {}).get("median"), total_stages)
        bound = r["flops_g"]["total"] / max(v for k, v in gemm.items() if k.endswith("fp32")) * 1e3  # the best fp32 GEMM measured
        rss = r["bench_fp32"]["peak_rss_mb"].get(str(results["ratio_threads"]))
        compiled = f"{comp_ms:.0f}" if comp_ms else r["torch_compile"].get("error", "-")
        openvino_ms = f"{ov_ms:.0f}" if ov_ms else r["openvino"].get("error")
        lines.append(f"| {arch} | {r['flops_g']['total']:.0f} | {fp32:.0f} | {int8:.0f} | {eager:.0f} | {compiled} | "
                     f"{openvino_ms} | {f'{share:.1%}' if share else '-'} | {bound:.0f} | {f'{rss:.0f}' if rss else '-'} |")
        targets.append((f"{arch} ORT fp32 vs eager >= {TARGETS[arch]}x", _ratio(eager, fp32), TARGETS[arch], True))
        targets.append((f"{arch} ORT fp32 vs torch.compile >= 1x", _ratio(comp_ms, fp32), 1.0, True))
        targets.append((f"{arch} ORT fp32 vs OpenVINO >= 1x", _ratio(ov_ms, fp32), 1.0, True))
        targets.append((f"{arch} fp32 time / FLOP-bound time <= 1.5", fp32 / bound, 1.5, False))
        targets.append((f"{arch} int8 speed-up over fp32 (e2e) >= 2.5x", _ratio(alt["ort_fp32_e2e"], int8), 2.5, True))
        targets.append((f"{arch} int8 top-50 matched >= 95%", r["int8_parity"]["top_matched_fraction"], 0.95, True))
        if arch == "fisheye-bevdet":
            targets.append(("fisheye-bevdet warp+lift+pooling share < 8%", share, 0.08, False))
            targets.append(("fisheye-bevdet peak RSS < 1500 MB", rss, 1500, False))
        svc = r["service"]
        if "service_ms" in svc:
            decode = f"; JPEG decode {np.median(svc['decode_ms']):.0f} ms of it" if svc.get("decode_ms") else ""
            overhead = float(np.median(svc["service_ms"])) / float(np.median(svc["direct_ms"])) - 1
            targets.append((f"{arch} POST /detect JPEG overhead <= 15%{decode}", overhead, 0.15, False))
        else:
            targets.append((f"{arch} POST /detect overhead: {svc.get('error')}", None, 0.15, False))
    lines.append("")
    lines.append("| target | achieved | goal | verdict |")
    lines.append("|---|---|---|---|")
    for name, value, goal, higher in targets:
        if value is None:
            lines.append(f"| {name} | n/a | {goal:g} | not measured |")
            continue
        met = value >= goal if higher else value <= goal
        miss = "" if met else f" (missed by {abs(value / goal - 1):.0%})"
        lines.append(f"| {name} | {value:.3g} | {goal:g} | {'MET' if met else 'MISSED' + miss} |")
    return "\n".join(lines)


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--models", default="fisheye-bevdet,fisheye-petr")
    parser.add_argument("--threads", default="1,2", help="thread counts for the per-stage bench (default 1,2)")
    parser.add_argument("--batch", default="1,2,4")
    parser.add_argument("--ratio-threads", type=int, default=2, help="threads for the ratio comparisons (default 2)")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--no-compile", dest="compile", action="store_false")
    parser.add_argument("--no-service", dest="service", action="store_false")
    args = parser.parse_args()
    args.threads = [int(x) for x in args.threads.split(",")]
    args.batch = [int(x) for x in args.batch.split(",")]
    start = time.perf_counter()
    results: dict[str, Any] = {"command": " ".join(sys.argv), "ratio_threads": args.ratio_threads}
    results["gemm_gflops"] = gemm_peak(args.ratio_threads)
    results["models"] = {arch: measure(arch, args) for arch in args.models.split(",")}
    results["seconds"] = time.perf_counter() - start
    (ART / "results.json").write_text(json.dumps(results, indent=2, default=float))
    from fisheye_infer.bench import format_table

    for r in results["models"].values():
        print(format_table(r["bench_fp32"]))
        print(format_table(r["bench_int8"]))
    print(report(results))
    print(f"figures: {ART / 'results.json'}; took {results['seconds']:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
