"""The runs a parity check compares: the PyTorch model's, and an ONNX file's in ONNX Runtime's CPU provider,
with the ranking values (``RANKING_OUTPUTS``) as outputs of both.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnx
import torch
from torch import nn

from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, RANKING_OUTPUTS
from fisheye_infer.runtime.denormals import flushed_denormals
from fisheye_infer.runtime.session import create_session

from .graph import save_model, with_outputs

__all__ = ["Outputs", "PROBE", "checked_graph", "run_onnx", "run_torch"]

Outputs = dict[str, np.ndarray]
#: What the checked graph outputs: the file's outputs, then the ranking values.
PROBE = OUTPUTS + RANKING_OUTPUTS


@torch.no_grad()
def run_torch(model: nn.Module, images: np.ndarray, valid: np.ndarray) -> Outputs:
    """PyTorch's outputs and ranking outputs."""
    out = model(torch.from_numpy(images), torch.from_numpy(valid))
    return {k: out[k].cpu().numpy() for k in PROBE}


def run_onnx(
    path: str | Path,
    images: np.ndarray,
    valid: np.ndarray,
    threads: int,
    outputs: Sequence[str] = OUTPUTS,
    *,
    per_frame: bool = False,
) -> Outputs:
    """``outputs`` of the file on the batch, in ONNX Runtime's CPU provider. ``per_frame``: each frame
    run alone (batch 1, as a deployed detector runs; batch-1 memory) in the one session, concatenated."""
    session = create_session(path, threads=threads, providers=["CPUExecutionProvider"])
    batches = [slice(i, i + 1) for i in range(len(images))] if per_frame else [slice(None)]
    with flushed_denormals():
        runs = [session.run(list(outputs), {INPUT_IMAGES: images[b], INPUT_CAMERA_VALID: valid[b]}) for b in batches]
    return {name: np.concatenate([r[k] for r in runs]) for k, name in enumerate(outputs)}


def checked_graph(path: str | Path, out: str | Path) -> Path:
    """Write the file ``path`` with its ranking values (``RANKING_OUTPUTS``) as extra outputs to ``out``."""
    model = onnx.load(str(path))
    return save_model(
        with_outputs(model, {"rank_scores": onnx.TensorProto.FLOAT, "rank_indices": onnx.TensorProto.INT64}), out
    )
