"""The frames an export is checked on: seeded synthetic renders of the rig, then the user's own.

The fp32 file's check against PyTorch and a reduced-precision file's comparison with its fp32 file
use the seeds 0, 1, ... (so the first comparison frames are the fp32 check's own); int8
calibration uses seeds from ``CALIBRATION_SEED``, so it never calibrates on a frame it is judged on.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ExportError
from fisheye_infer.runtime.preprocess import Frame, frames_from_paths, prepare_batch
from fisheye_infer.scenes.render import Renderer, random_scene

__all__ = ["CALIBRATION_SEED", "verification_frames"]

#: Calibration frames are rendered from seeds offset by this, disjoint from the verification seeds.
CALIBRATION_SEED = 1000


def verification_frames(rig: Rig, count: int, seed: int = 0, images: str | Path | None = None) -> np.ndarray:
    """(F, N, H, W, 3) uint8: ``count`` seeded synthetic renders of the rig, then the user's frames.

    User frames come from a folder, as ``fisheye_infer.runtime.preprocess.frames_from_paths`` reads it.
    """
    renderer = Renderer(texture_seed=seed)
    frames: list[Frame] = [renderer.render(rig, random_scene(np.random.default_rng(seed + i))) for i in range(count)]
    if images is not None:
        frames.extend(frame for _, frame in frames_from_paths([images], rig.names))
    if not frames:
        raise ExportError("verification needs at least one frame")
    width, height = rig.cameras[0].model.width, rig.cameras[0].model.height
    batch, _ = prepare_batch(frames, rig.names, (width, height))
    return batch
