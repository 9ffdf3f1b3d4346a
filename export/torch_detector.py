"""``TorchDetector``: the PyTorch model behind the runtime's ``Detector`` interface.

    loaded = open_checkpoint("model.pth", config="config.py", rig="rig.json")
    torch_side = TorchDetector(loaded.model, like="model.onnx")     # the file exported from it
    torch_side.detect(frame)                                         # Detections, as Detector gives

Decoding, frame checks, stacking and post-processing are ``FrameDetector``'s, shared with
``Detector`` (ONNX Runtime) and ``TritonDetector``; only the graph run differs. So a metric computed
through both (``fisheye-infer eval``'s loop) compares the exported file with the model it came
from, and nothing else.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch
from torch import nn

from fisheye_infer.runtime.artifact import OUTPUTS, read_meta
from fisheye_infer.runtime.detector import FrameDetector, describe
from fisheye_infer.runtime.nms import NmsConfig

__all__ = ["TorchDetector"]


class TorchDetector(FrameDetector):
    """Runs ``model`` (eval mode, float32, CPU) for frames described by the exported file ``like``."""

    def __init__(
        self,
        model: nn.Module,
        like: str | Path,
        *,
        score_threshold: float | None = None,
        nms: NmsConfig | str | None = None,
    ) -> None:
        super().__init__(describe(read_meta(like), ("torch",)), score_threshold=score_threshold, nms=nms)
        self.model = model.eval()

    @torch.no_grad()
    def _run(self, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
        out = self.model(torch.from_numpy(images), torch.from_numpy(valid))
        return [out[name].cpu().numpy() for name in OUTPUTS]
