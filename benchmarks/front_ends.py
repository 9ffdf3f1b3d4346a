"""The pinhole baselines' front end, Pillow's resize and the crop, as a share of a frame.

    python benchmarks/front_ends.py [--models pinhole-bevdet pinhole-petr] [--threads 1 2] [--quick]

For each pinhole architecture (full size, seeded weights: ``make_checkpoint(name, seed=0)``, the six-camera
pinhole rig):
1. the whole file, written by ``export`` once (kept under ``benchmarks/artifacts/front_ends/``);
2. the front end alone: the model's own ``views`` (Pillow's bicubic resize and the crop, before the
   normalisation) on the same ``geom.resize.*`` tables, traced the same way into a file of its own;
3. both on the export's verification frame, in ONNX Runtime with the runtime's session options, each session
   timed alone in blocks after warm-up (``harness.alternate``: two sessions timed call by call slow each other
   through their spinning worker threads), at each ``--threads``.

The front end's share is its time over the whole file's.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import harness
import numpy as np
import torch
from model_files import ARTIFACTS

from fisheye_infer.cameras.default_rigs import pinhole_rig
from fisheye_infer.export.exporter import export, open_checkpoint, verification_frames
from fisheye_infer.models import make_checkpoint
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, read_meta
from fisheye_infer.runtime.session import create_session

MODELS = ("pinhole-bevdet", "pinhole-petr")


class FrontEnd(torch.nn.Module):
    """A pinhole model's ``views`` on its own geometry tables, as a module of its own."""

    def __init__(self, model: Any) -> None:
        super().__init__()
        self.model = model
        self.tables = model.geometry_tables()

    def forward(self, images: torch.Tensor) -> torch.Tensor:
        return self.model.views(images, self.tables)


def files(name: str) -> tuple[Path, Path]:
    """The whole file and the front end's file of architecture ``name``, written where missing."""
    folder = ARTIFACTS / "front_ends" / name
    folder.mkdir(parents=True, exist_ok=True)
    checkpoint, whole, front = folder / "model.pth", folder / "model.onnx", folder / "front_end.onnx"
    rig = pinhole_rig()
    if not checkpoint.exists():
        make_checkpoint(name, seed=0, path=checkpoint, rig=rig)
    if not whole.exists():
        export(checkpoint, whole, arch=name, rig=rig, frames=1)
    if not front.exists():
        model = open_checkpoint(checkpoint, arch=name, rig=rig).model.eval()
        images = torch.from_numpy(verification_frames(read_meta(whole).rig, 1))
        with torch.no_grad():
            torch.onnx.export(FrontEnd(model), (images,), str(front), dynamo=True, input_names=[INPUT_IMAGES])
    return whole, front


def main() -> int:
    bench = harness.Benchmark(__file__, __doc__, quick="2 rounds of 1")
    bench.parser.add_argument("--models", nargs="+", default=list(MODELS), help="pinhole architectures")
    bench.parser.add_argument("--threads", nargs="+", type=int, default=[1, 2])
    args = bench.parse()
    rounds, repeat = (2, 1) if args.quick else (5, 3)
    rows = []
    for name in args.models:
        whole, front = files(name)
        images = verification_frames(read_meta(whole).rig, 1)
        feeds = {INPUT_IMAGES: images, INPUT_CAMERA_VALID: np.ones(images.shape[:2], bool)}
        for threads in args.threads:
            calls = {
                "whole": harness.session_call(create_session(whole, threads=threads), feeds),
                "front": harness.session_call(create_session(front, threads=threads), {INPUT_IMAGES: images}),
            }
            times = harness.alternate(calls, rounds=rounds, repeat=repeat)
            rows.append(
                {
                    "model": name,
                    "input": f"{images.shape[1]} x {images.shape[3]}x{images.shape[2]}",
                    "threads": threads,
                    "whole file ms": times["whole"].median,
                    "front end ms": times["front"].median,
                    "front end share": times["front"].median / times["whole"].median,
                }
            )
            print(rows[-1], flush=True)
    bench.save(args, {"The front end's share of a frame": rows})
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
