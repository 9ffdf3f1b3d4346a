"""An exported file on a GPU: ONNX Runtime's CUDA provider, what float16 and TF32 change, PyTorch beside it.

    pip install onnxruntime-gpu   # in place of onnxruntime (CUDA 13; cuDNN 9 from the nvidia-* wheels or the system)
    python benchmarks/gpu.py --onnx compact            # a shipped or seeded model by name: its files and checkpoint
    python benchmarks/gpu.py --onnx model.onnx --ckpt model.pth [--config CFG --rig RIG]

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

import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import harness
import numpy as np
import onnxruntime as ort
from model_files import NAMES, model_files

from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES
from fisheye_infer.runtime.session import Provider


def median_ms(fn: Callable[[], object], repeat: int, sync: Callable[[], object] = lambda: None) -> float:
    """Median ms of ``repeat`` calls after 5 warm-up calls; ``sync`` waits for the GPU before the clock is read."""
    return harness.measure(fn, repeat, warmup=5, sync=sync).median


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
        feed = {
            INPUT_IMAGES: np.ascontiguousarray(frames[:batch]),
            INPUT_CAMERA_VALID: np.ones(frames[:batch].shape[:2], bool),
        }
        out[f"run b{batch}, numpy in and out, ms"] = median_ms(lambda feed=feed: session.run(names, feed), repeat)
        binding = session.io_binding()
        for name, value in feed.items():
            binding.bind_ortvalue_input(name, ort.OrtValue.ortvalue_from_numpy(value, device, 0))
        for name in names:
            binding.bind_output(name, device)
        bound = lambda b=binding: session.run_with_iobinding(b)  # noqa: E731
        out[f"run b{batch}, bound to the device, ms"] = median_ms(bound, repeat, sync=binding.synchronize_outputs)
    return out


def parity(fp32: Path, candidate: Path, frames: np.ndarray, providers: list[Provider]) -> dict[str, Any]:
    from fisheye_infer.export.fp16_parity import fp16_parity

    p = fp16_parity(fp32, candidate, frames, threads=4, candidate_providers=providers)
    return {
        "evaluated_with": p.evaluated_with,
        "top50_matched": p.top_matched_fraction,
        "max_box_m": p.max_box_abs_diff_m,
        "max_score": p.max_score_abs_diff,
        "dense_scores_max": p.max_rank_score_abs_diff,
        "at_own_choice": p.replayed.model_dump() if p.replayed else None,
        "problems": list(p.problems),
    }


def torch_timings(
    ckpt: Path, config: str | None, rig: str | None, frames: np.ndarray, repeat: int
) -> tuple[str, list[dict[str, Any]]]:
    """PyTorch's version and device, and a row per way of running the model: eager fp32, eager under
    autocast (float16 on a GPU, bfloat16 on a CPU), torch.compile (with the time compiling took)."""
    import torch

    from fisheye_infer.export.exporter import open_checkpoint

    device = "cuda" if torch.cuda.is_available() else "cpu"
    sync = torch.cuda.synchronize if device == "cuda" else (lambda: None)
    model = open_checkpoint(ckpt, config=config, rig=rig).model.eval().to(device)
    half = torch.float16 if device == "cuda" else torch.bfloat16
    rows: list[dict[str, Any]] = []
    with torch.inference_mode():
        for batch in (1, 4):
            x = torch.from_numpy(frames[:batch]).to(device)
            valid = torch.ones(x.shape[:2], dtype=torch.bool, device=device)
            run = lambda x=x, valid=valid: model(x, valid)  # noqa: E731
            rows.append({"mode": "eager fp32", "batch": batch, "median ms": median_ms(run, repeat, sync=sync)})
            with torch.autocast(device, dtype=half):
                ms = median_ms(run, repeat, sync=sync)
                rows.append({"mode": f"eager, {half} autocast", "batch": batch, "median ms": ms})
        x = torch.from_numpy(frames[:1]).to(device)
        valid = torch.ones(frames[:1].shape[:2], dtype=torch.bool, device=device)
        t0 = time.perf_counter()
        compiled = torch.compile(model)
        compiled(x, valid)
        sync()
        compile_s = time.perf_counter() - t0
        ms = median_ms(lambda: compiled(x, valid), repeat, sync=sync)
        rows.append({"mode": "torch.compile fp32", "batch": 1, "median ms": ms, "compile s": compile_s})
    name = torch.cuda.get_device_name() if device == "cuda" else "cpu"
    return f"PyTorch {torch.__version__} on {name}", rows


def main(argv: list[str] | None = None) -> int:
    bench = harness.Benchmark(__file__, __doc__)
    p = bench.parser
    p.add_argument(
        "--onnx",
        required=True,
        help="the verified fp32 file (its .fp16.onnx sibling too, when present), "
        "or one of compact, fisheye-bevdet, fisheye-petr",
    )
    p.add_argument("--ckpt", type=Path, help="the checkpoint it was exported from: adds PyTorch's figures")
    p.add_argument("--config", help="the checkpoint's config, as for export")
    p.add_argument("--rig", help="the checkpoint's rig, as for export")
    p.add_argument("--verify-images", help="a frame folder added to the seeded frames, as for export")
    p.add_argument("--repeat", type=int, default=30)
    args = bench.parse(argv)
    if args.onnx in NAMES:
        named = model_files(args.onnx)
        args.onnx, args.ckpt = named.fp32, args.ckpt or named.checkpoint
        args.config, args.rig = args.config or named.config, args.rig or named.rig
    args.onnx = Path(args.onnx)

    from fisheye_infer.export.exporter import fp16_path_for, verification_frames
    from fisheye_infer.runtime.artifact import read_meta

    frames = verification_frames(read_meta(args.onnx).rig, 2, images=args.verify_images)
    batch4 = np.concatenate([frames] * 2)[:4]
    files = {"fp32": args.onnx}
    if fp16_path_for(args.onnx).is_file():
        files["fp16"] = fp16_path_for(args.onnx)
    rows = []
    runs = [(kind, path, True) for kind, path in files.items()] + [("fp32, TF32 off", args.onnx, False)]
    for kind, path, tf32 in runs:
        print(f"{kind}: parity and timings", file=sys.stderr)
        providers = cuda_providers(tf32)
        parity_ = parity(args.onnx, path, frames, providers)
        times = ort_timings(path, batch4, providers, args.repeat)
        rows.append(
            {
                "file": kind,
                "provider": times.pop("providers")[0],
                "top-50 matched vs fp32 on CPU": parity_["top50_matched"],
                "max box diff m": parity_["max_box_m"],
                "max score diff": parity_["max_score"],
                **times,
                "problems": parity_["problems"],
            }
        )
    tables: dict[str, list[dict[str, Any]]] = {f"ONNX Runtime {ort.__version__}, graph run": rows}
    if args.ckpt:
        print("PyTorch", file=sys.stderr)
        title, torch_rows = torch_timings(args.ckpt, args.config, args.rig, batch4, args.repeat)
        tables[title] = torch_rows
    bench.save(args, tables)
    return 0


if __name__ == "__main__":
    sys.exit(main())
