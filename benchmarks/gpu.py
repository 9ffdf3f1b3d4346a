"""An exported file on a GPU: ONNX Runtime's CUDA provider, what float16 and TF32 change, PyTorch beside it.

    pip install onnxruntime-gpu   # in place of onnxruntime (the CUDA 13 build; cuDNN 9 from the nvidia-* wheels or the system)
    python benchmarks/gpu.py --onnx model.onnx --ckpt model.pth [--config CFG --rig RIG] --out gpu.json

For the fp32 file and its fp16 file (``model.fp16.onnx`` beside it, when ``export --fp16`` wrote
one), in the CUDA provider:

- parity against the fp32 file in the CPU provider (``fp16_parity``: the share of the fp32 top-50
  boxes found again within 0.5 m with the same label, box and score differences, and the same at
  the candidate's own top-k choice), on the export's verification frames;
- the graph run's median time at batch 1 and 4, from numpy arrays (``session.run``: copies in and
  out included) and with inputs and outputs bound to GPU memory (the kernels alone);
- all of it with ONNX Runtime's CUDA defaults (TF32 in convolutions and matrix products) and, for
  the fp32 file, with ``use_tf32`` off (what a bit-faithful fp32 run costs).

With ``--ckpt``, PyTorch on the same GPU: eager fp32 (PyTorch's defaults: TF32 convolutions),
eager under float16 autocast, and ``torch.compile``. The end-to-end figures with decoding and
post-processing are ``fisheye-infer bench MODEL --providers CUDAExecutionProvider,CPUExecutionProvider``.
Without a GPU (no CUDA provider, no CUDA device) the script runs on the CPU, to check it runs.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import onnxruntime as ort

from fisheye_infer.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES
from fisheye_infer.session import Provider


def median_ms(fn: Callable[[], object], repeat: int, warmup: int = 5, sync: Callable[[], object] = lambda: None) -> float:
    for _ in range(warmup):
        fn()
    sync()
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        sync()
        times.append((time.perf_counter() - t0) * 1e3)
    return round(statistics.median(times), 2)


def cuda_providers(tf32: bool = True) -> list[Provider]:
    """The CUDA provider then the CPU, or the CPU alone where no CUDA provider is installed (a dry run)."""
    if "CUDAExecutionProvider" not in ort.get_available_providers():
        return ["CPUExecutionProvider"]
    return [("CUDAExecutionProvider", {"use_tf32": "1" if tf32 else "0"}), "CPUExecutionProvider"]


def ort_timings(path: Path, frames: np.ndarray, providers: list[Provider], repeat: int) -> dict[str, Any]:
    session = ort.InferenceSession(str(path), providers=providers)
    device = "cuda" if session.get_providers()[0] == "CUDAExecutionProvider" else "cpu"
    names = [o.name for o in session.get_outputs()]
    out: dict[str, Any] = {"providers": session.get_providers()}
    for batch in (1, 4):
        feed = {INPUT_IMAGES: np.ascontiguousarray(frames[:batch]), INPUT_CAMERA_VALID: np.ones(frames[:batch].shape[:2], bool)}
        out[f"numpy_b{batch}_ms"] = median_ms(lambda feed=feed: session.run(names, feed), repeat)
        binding = session.io_binding()
        for name, value in feed.items():
            binding.bind_ortvalue_input(name, ort.OrtValue.ortvalue_from_numpy(value, device, 0))
        for name in names:
            binding.bind_output(name, device)
        out[f"bound_b{batch}_ms"] = median_ms(lambda b=binding: session.run_with_iobinding(b), repeat, sync=binding.synchronize_outputs)
    return out


def parity(fp32: Path, candidate: Path, frames: np.ndarray, providers: list[Provider]) -> dict[str, Any]:
    from fisheye_infer.export.fp16_parity import fp16_parity

    p = fp16_parity(fp32, candidate, frames, threads=4, candidate_providers=providers)
    return {"evaluated_with": p.evaluated_with, "top50_matched": p.top_matched_fraction, "max_box_m": p.max_box_abs_diff_m,
            "max_score": p.max_score_abs_diff, "dense_scores_max": p.max_rank_score_abs_diff,
            "at_own_choice": p.replayed.model_dump() if p.replayed else None, "problems": list(p.problems)}


def torch_timings(ckpt: Path, config: str | None, rig: str | None, frames: np.ndarray, repeat: int) -> dict[str, Any]:
    import torch

    from fisheye_infer.export.exporter import open_checkpoint

    device = "cuda" if torch.cuda.is_available() else "cpu"
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    model = open_checkpoint(ckpt, config=config, rig=rig).model.eval().to(device)
    out: dict[str, Any] = {"torch": torch.__version__, "device": torch.cuda.get_device_name() if device == "cuda" else "cpu"}
    with torch.inference_mode():
        for batch in (1, 4):
            x = torch.from_numpy(frames[:batch]).to(device)
            valid = torch.ones(x.shape[:2], dtype=torch.bool, device=device)
            run = lambda x=x, valid=valid: model(x, valid)  # noqa: E731
            out[f"eager_fp32_b{batch}_ms"] = median_ms(run, repeat, sync=sync)
            with torch.autocast(device, dtype=torch.float16 if device == "cuda" else torch.bfloat16):
                out[f"eager_autocast_b{batch}_ms"] = median_ms(run, repeat, sync=sync)
        x, valid = torch.from_numpy(frames[:1]).to(device), torch.ones(frames[:1].shape[:2], dtype=torch.bool, device=device)
        t0 = time.perf_counter()
        compiled = torch.compile(model)
        compiled(x, valid)
        sync()
        out["compile_s"] = round(time.perf_counter() - t0, 1)
        out["compiled_fp32_b1_ms"] = median_ms(lambda: compiled(x, valid), repeat, sync=sync)
    return out


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--onnx", type=Path, required=True, help="the verified fp32 file (its .fp16.onnx sibling is used when present)")
    parser.add_argument("--ckpt", type=Path, help="the checkpoint it was exported from: adds PyTorch's figures")
    parser.add_argument("--config", help="the checkpoint's config, as for export")
    parser.add_argument("--rig", help="the checkpoint's rig, as for export")
    parser.add_argument("--verify-images", help="a frame folder added to the seeded frames, as for export")
    parser.add_argument("--repeat", type=int, default=30)
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()

    from fisheye_infer.artifact import read_meta
    from fisheye_infer.bench import machine
    from fisheye_infer.export.exporter import fp16_path_for, verification_frames

    frames = verification_frames(read_meta(args.onnx).rig, 2, images=args.verify_images)
    batch4 = np.concatenate([frames] * 2)[:4]
    files = {"fp32": args.onnx}
    if fp16_path_for(args.onnx).is_file():
        files["fp16"] = fp16_path_for(args.onnx)
    result: dict[str, Any] = {"machine": machine(), "onnxruntime": ort.__version__, "files": {}}
    runs = [(kind, path, True) for kind, path in files.items()] + [("fp32, TF32 off", args.onnx, False)]
    for kind, path, tf32 in runs:
        print(f"{kind}: parity and timings", file=sys.stderr)
        providers = cuda_providers(tf32)
        result["files"][kind] = {"file": str(path), "parity_vs_fp32_cpu": parity(args.onnx, path, frames, providers),
                                 **ort_timings(path, batch4, providers, args.repeat)}
    if args.ckpt:
        print("PyTorch", file=sys.stderr)
        result["torch"] = torch_timings(args.ckpt, args.config, args.rig, batch4, args.repeat)
    print(report(result))
    if args.out:
        args.out.write_text(json.dumps(result, indent=2))
    return 0


def report(result: dict[str, Any]) -> str:
    m = result["machine"]
    lines = [f"GPU: {', '.join(m['gpus']) or 'none'}; CPU: {m['cpu']}, {m['cpu_count']} cores; onnxruntime {result['onnxruntime']}",
             "file | providers | top-50 matched vs fp32 on CPU | max box m / score | run b1 ms (numpy / bound) | run b4 ms (numpy / bound)"]
    for kind, r in result["files"].items():
        p = r["parity_vs_fp32_cpu"]
        lines.append(f"{kind} | {r['providers'][0]} | {p['top50_matched']:.1%} | {p['max_box_m']:.3f} / {p['max_score']:.4f} | "
                     f"{r['numpy_b1_ms']} / {r['bound_b1_ms']} | {r['numpy_b4_ms']} / {r['bound_b4_ms']}")
    if "torch" in result:
        t = result["torch"]
        lines.append(f"PyTorch {t['torch']} on {t['device']}: eager fp32 b1 {t['eager_fp32_b1_ms']} ms, b4 {t['eager_fp32_b4_ms']} ms; "
                     f"float16 autocast b1 {t['eager_autocast_b1_ms']} ms, b4 {t['eager_autocast_b4_ms']} ms; "
                     f"torch.compile b1 {t['compiled_fp32_b1_ms']} ms (compiling took {t['compile_s']} s)")
    return "\n".join(lines)


if __name__ == "__main__":
    sys.exit(main())
