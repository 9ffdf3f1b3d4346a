"""Evidence for an int8 file: its detections against the verified fp32 file's, on the same frames.

int8 is not expected to reproduce fp32 to 1e-3 m, so the criterion is detection-level, the one
shared with fp16 (``fp16_parity``): the share of the fp32 file's top-50 boxes found again within
0.5 m with the same label (``fisheye_infer.eval.top_match``). Both files run in ONNX Runtime's CPU
execution provider, where the int8 file is meant to run. Kept apart from ``quantize``, which makes
the file: this only reads two files, and ``reduced.export_int8`` decides with its report whether the
int8 file is written.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from fisheye_infer.eval.top_match import MATCH_RADIUS_M, top_matched
from fisheye_infer.precision import MIN_TOP_MATCHED
from fisheye_infer.runtime.artifact import OUTPUTS, ReducedParityReport

from .parity_runs import run_onnx

__all__ = ["file_outputs", "int8_parity"]


def file_outputs(path: str | Path, frames: np.ndarray, threads: int = 2) -> list[np.ndarray]:
    """A file's ``OUTPUTS`` on ``frames`` (every camera present), one frame at a time, as a deployed
    detector runs: the fp32 side of ``int8_parity``, computed once when many int8 files are judged."""
    valid = np.ones(frames.shape[:2], bool)
    outputs = run_onnx(path, frames, valid, threads, per_frame=True)
    return [outputs[k] for k in OUTPUTS]


def int8_parity(
    fp32_path: str | Path,
    int8_path: str | Path,
    frames: np.ndarray,
    threads: int = 2,
    min_fraction: float = MIN_TOP_MATCHED,
    *,
    reference: Sequence[np.ndarray] | None = None,
) -> ReducedParityReport:
    """The int8 file against the fp32 ONNX file on ``frames``, one frame at a time.

    int8 is not expected to reproduce fp32 to 1e-3 m; the criterion is detection-level: at
    least ``min_fraction`` of the fp32 top-50 boxes found again within 0.5 m with the same label.
    ``reference``: the fp32 file's ``file_outputs`` on these frames, when already computed.
    """
    ref = file_outputs(fp32_path, frames, threads) if reference is None else list(reference)
    cand = file_outputs(int8_path, frames, threads)
    kept = top_matched(ref, cand)
    return ReducedParityReport(
        frames=len(frames),
        threads=(threads,),
        top_matched_fraction=kept.fraction,
        top_matched_standard_error=kept.standard_error,
        top_matched_by_score=kept.by_score,
        min_top_matched=min_fraction,
        match_radius_m=MATCH_RADIUS_M,
        unmatched=kept.considered - kept.matched,
        max_box_abs_diff_m=kept.max_box_diff,
        max_score_abs_diff=kept.max_score_diff,
        labels_equal=bool(np.array_equal(ref[2], cand[2])),
        valid_equal=bool(np.array_equal(ref[3], cand[3])),
        passed=kept.fraction >= min_fraction,
    )
