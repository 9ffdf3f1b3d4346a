"""Parity: the exported file in ONNX Runtime against the PyTorch model, on the same frames.

Every export ends here. Every box of the PyTorch output must have its counterpart in the ONNX
output: the same label and validity, the box within 1e-3 m and the score within 1e-4. Position
by position is the rule; a swap between boxes whose scores are equal to within the score
tolerance is allowed (top-k order among such ties is not defined) and counted, and a box that
ties the last kept score may fall off the end. Whether labels and order are identical position
by position is reported too. It runs at each requested intra-op thread count (pooling
must be deterministic under threads) and with a batch of all frames (the dynamic batch axis).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

import numpy as np
import onnxruntime as ort
import torch
from torch import nn

from fisheye_infer.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, ParityReport

__all__ = ["TOLERANCE_BOX_M", "TOLERANCE_SCORE", "compare_outputs", "run_onnx", "run_torch", "verify"]

TOLERANCE_BOX_M = 1e-3
TOLERANCE_SCORE = 1e-4


@dataclass(frozen=True)
class _Diff:
    box: float  # over matched pairs
    score: float
    labels_equal: bool  # position by position
    order_equal: bool  # position by position: same boxes in the same order
    valid_equal: bool
    swaps: int  # pairs found at another position, among near-equal scores
    unmatched: int  # reference boxes with no counterpart (boundary ties excepted)


def _box_diff(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Max abs difference per box pair, yaw compared on the circle (+pi == -pi)."""
    d = np.abs(a.astype(np.float64) - b.astype(np.float64))
    d[..., 6] = np.minimum(d[..., 6], np.abs(2 * np.pi - d[..., 6]))
    return d.max(axis=-1)


def _match_sample(rb: np.ndarray, rs: np.ndarray, rl: np.ndarray, cb: np.ndarray, cs: np.ndarray, cl: np.ndarray) -> tuple[list[int], int, int]:
    """Counterpart in the candidate of each reference box; -1 where none.

    A box matches at its own position when label and box agree; otherwise any unused candidate
    with the same label, a box within tolerance and a score within tolerance counts (top-k order
    among scores equal to float precision is not defined). Unmatched boxes whose score ties the
    last kept score are boundary ties and are not counted as failures.
    """
    k = len(rb)
    used = np.zeros(k, bool)
    match = [-1] * k
    swaps = unmatched = 0
    for i in range(k):
        if rl[i] == cl[i] and _box_diff(rb[i], cb[i]) <= TOLERANCE_BOX_M:
            match[i], used[i] = i, True
    for i in range(k):
        if match[i] >= 0:
            continue
        near = np.flatnonzero(~used & (cl == rl[i]) & (np.abs(cs - rs[i]) <= TOLERANCE_SCORE))
        near = [j for j in near if _box_diff(rb[i], cb[j]) <= TOLERANCE_BOX_M]
        if near:
            match[i], used[near[0]] = near[0], True
            swaps += 1
        elif rs[i] > rs.min() + TOLERANCE_SCORE:
            unmatched += 1
    return match, swaps, unmatched


def compare_outputs(reference: Sequence[np.ndarray], candidate: Sequence[np.ndarray]) -> _Diff:
    """Compare batches of (boxes, scores, labels, valid) from two runs of the same model."""
    rb, rs, rl, rv = reference
    cb, cs, cl, cv = candidate
    box = score = 0.0
    swaps = unmatched = 0
    valid_equal = True
    for b in range(len(rb)):
        match, s, u = _match_sample(rb[b], rs[b], rl[b], cb[b], cs[b], cl[b])
        swaps, unmatched = swaps + s, unmatched + u
        pairs = [(i, j) for i, j in enumerate(match) if j >= 0]
        if pairs:
            i, j = (np.array(v) for v in zip(*pairs))
            box = max(box, float(_box_diff(rb[b][i], cb[b][j]).max()))
            score = max(score, float(np.abs(rs[b][i].astype(np.float64) - cs[b][j]).max()))
            valid_equal &= bool(np.array_equal(rv[b][i], cv[b][j]))
    return _Diff(
        box=box,
        score=score,
        labels_equal=bool(np.array_equal(rl, cl)),
        order_equal=bool(np.array_equal(rl, cl) and np.all(_box_diff(rb, cb) <= TOLERANCE_BOX_M)),
        valid_equal=valid_equal,
        swaps=swaps,
        unmatched=unmatched,
    )


@torch.no_grad()
def run_torch(model: nn.Module, images: np.ndarray, valid: np.ndarray) -> list[np.ndarray]:
    out = model(torch.from_numpy(images), torch.from_numpy(valid))
    return [out[k].cpu().numpy() for k in OUTPUTS]


def run_onnx(path: str | Path, images: np.ndarray, valid: np.ndarray, threads: int) -> list[np.ndarray]:
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    return session.run(list(OUTPUTS), {INPUT_IMAGES: images, INPUT_CAMERA_VALID: valid})


def verify(path: str | Path, model: nn.Module, frames: np.ndarray, valid: np.ndarray | None = None, threads: Sequence[int] = (1, 2)) -> ParityReport:
    """Compare ``path`` in ORT with ``model`` on ``frames`` (F, N, H, W, 3) uint8, one by one and batched."""
    if valid is None:
        valid = np.ones(frames.shape[:2], dtype=bool)
    singles = [run_torch(model, frames[i : i + 1], valid[i : i + 1]) for i in range(len(frames))]
    reference = [np.concatenate([s[k] for s in singles]) for k in range(len(OUTPUTS))]
    diffs = []
    for t in threads:
        one_by_one = [run_onnx(path, frames[i : i + 1], valid[i : i + 1], t) for i in range(len(frames))]
        diffs.append(compare_outputs(reference, [np.concatenate([o[k] for o in one_by_one]) for k in range(len(OUTPUTS))]))
    diffs.append(compare_outputs(reference, run_onnx(path, frames, valid, threads[-1])))
    box = max(d.box for d in diffs)
    score = max(d.score for d in diffs)
    labels_equal = all(d.labels_equal for d in diffs)
    order_equal = all(d.order_equal for d in diffs)
    valid_equal = all(d.valid_equal for d in diffs)
    swaps = max(d.swaps for d in diffs)
    unmatched = max(d.unmatched for d in diffs)
    return ParityReport(
        frames=len(frames),
        threads=tuple(threads),
        max_box_abs_diff_m=box,
        max_score_abs_diff=score,
        labels_equal=labels_equal,
        order_equal=order_equal,
        valid_equal=valid_equal,
        tie_swaps=swaps,
        unmatched=unmatched,
        tolerance_box_m=TOLERANCE_BOX_M,
        tolerance_score=TOLERANCE_SCORE,
        passed=bool(box <= TOLERANCE_BOX_M and score <= TOLERANCE_SCORE and unmatched == 0 and valid_equal),
    )
