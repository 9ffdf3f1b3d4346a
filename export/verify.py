"""The export check: the graph in ONNX Runtime against the PyTorch model, on the same frames.

Every export ends here. The reference is the PyTorch model evaluated in float64, and the graph
must be about as close to it as PyTorch's own float32 evaluation is: for each compared quantity
the graph's largest difference from float64 may be at most ``SLACK`` times PyTorch float32's on
the same frames and at the same top-k choices, and never needs to be below the fixed floors
(1e-4 for scores, 1e-3 m for boxes). With trained-like weights float32 itself drifts from the
exact answer by more than such fixed floors; a tolerance scaled by the measured float32 drift
holds on any CPU and any weights, while a wrong weight, table or operator is off by orders of
magnitude more.

What is compared is what is defined (see ``models.ranking``):

1. the dense scores each detector ranks, before any discrete step (TransFusion's sigmoid
   heatmap, PETR's sigmoid class scores), element by element;
2. the graph's discrete choices: the float64 model replays the ranking from the graph's own dense
   scores and must find the graph's indices to be a top-k of them (after local-max suppression,
   for TransFusion). Choices that differ from PyTorch float32's at tied or near-tied scores are
   allowed and counted (``tie_swaps``, ``tie_substitutions``);
3. every output box, position by position, against the float64 model at that same choice: the
   same label and validity, the box and the score within tolerance. No box may miss.

The graph checked is the file with its ranking values made outputs again (the written file
computes them but does not output them), and the file's own outputs must equal the checked
graph's. The check runs at each
requested intra-op thread count frame by frame, and with a batch of all frames (the dynamic
batch axis).

The measures and tolerances are ``parity_errors``'s, the runs compared ``parity_runs``'s and the
float64 model's answers at a given choice ``ranking_replay``'s.
"""

from __future__ import annotations

import copy
import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np
from torch import nn

from fisheye_infer.runtime.artifact import OUTPUTS, ParityReport
from fisheye_infer.runtime.box_geometry import box_diff

from .parity_errors import FLOOR_BOX_M, FLOOR_SCORE, SLACK, Errors, RunDiff
from .parity_runs import PROBE, Outputs, checked_graph, run_onnx, run_torch
from .ranking_replay import ExactAnswer, RankingHead

__all__ = [
    "FLOOR_BOX_M",
    "FLOOR_SCORE",
    "PROBE",
    "SLACK",
    "Errors",
    "Reference",
    "checked_graph",
    "compare_run",
    "run_onnx",
    "run_torch",
    "verify",
]


class Reference:
    """The float64 model replaying rankings, and PyTorch float32's own answers and drift.

    ``float32_errors`` is how far PyTorch float32 is from float64: on the dense scores, and on the
    boxes and scores at every ranking compared so far (its own, and each one replayed for a graph),
    so the tolerances always rest on float32's drift at the same choices the graph made.
    """

    def __init__(self, model: nn.Module, frames: np.ndarray, valid: np.ndarray | None = None) -> None:
        """``model`` on ``frames`` (F, N, H, W, 3) uint8 with cameras ``valid`` (F, N) (default: all)."""
        if valid is None:
            valid = np.ones(frames.shape[:2], dtype=bool)
        self.frames, self.valid = frames, valid
        self.single = RankingHead(model, frames, valid)
        self.double = RankingHead(copy.deepcopy(model).double().eval(), frames, valid)
        self.float32 = self.single.outputs
        self._cache: dict[tuple[int, bytes, bytes], ExactAnswer] = {}
        self.float32_errors = Errors()
        for f, out in enumerate(self.float32):
            self.float32_errors.update(self.diff(f, out)[0].errors)

    def __len__(self) -> int:
        return len(self.float32)

    def exact(self, frame: int, dense: np.ndarray, indices: np.ndarray) -> ExactAnswer:
        """The float64 answer of ``frame`` when the ranking starts from ``dense`` (M,) and picks ``indices`` (K,)."""
        key = (frame, np.ascontiguousarray(indices, np.int64).tobytes(), np.ascontiguousarray(dense).tobytes())
        if key not in self._cache:
            exact = self._cache[key] = self.double.replay(frame, dense, indices)
            single = self.single.replay(frame, dense, indices).out
            self.float32_errors.update(
                Errors(
                    float(np.abs(self.float32[frame]["rank_scores"][0].astype(np.float64) - exact.own_dense).max()),
                    float(box_diff(exact.out["boxes"][0], single["boxes"][0]).max()),
                    float(np.abs(exact.out["scores"][0] - single["scores"][0].astype(np.float64)).max()),
                )
            )
        return self._cache[key]

    def diff(self, frame: int, got: Outputs, row: int = 0) -> tuple[RunDiff, Outputs]:
        """How ``got[...][row]`` (one frame's outputs with ranking outputs) differs from float64."""
        diff = RunDiff()
        dense, chosen = got["rank_scores"][row], got["rank_indices"][row]
        exact = self.exact(frame, dense, chosen)
        if exact.problem:
            diff.selection_valid = False
            diff.notes.append(f"frame {frame}: the graph's choice is not a top-k of its own scores: {exact.problem}")
        box = box_diff(exact.out["boxes"][0], got["boxes"][row])
        score = np.abs(exact.out["scores"][0] - got["scores"][row].astype(np.float64))
        labels = exact.out["labels"][0] == got["labels"][row]
        valid = exact.out["valid"][0] == got["valid"][row]
        diff.errors = Errors(
            float(np.abs(dense.astype(np.float64) - exact.own_dense).max()), float(box.max()), float(score.max())
        )
        diff.boxes, diff.scores = [box], [score]
        diff.labels_equal, diff.valid_equal = bool(labels.all()), bool(valid.all())
        diff.other_label_or_validity = int(np.count_nonzero(~labels | ~valid))
        return diff, exact.out


def compare_run(reference: Reference, candidate: Outputs) -> RunDiff:
    """Compare one ORT run over all of ``reference``'s frames (a batch, with ranking outputs)."""
    total = RunDiff()
    for f in range(len(reference)):
        diff, _ = reference.diff(f, candidate, row=f)
        own = reference.float32[f]["rank_indices"][0]
        chosen = candidate["rank_indices"][f]
        swaps = int(np.count_nonzero(chosen != own))
        total.errors.update(diff.errors)
        total.boxes += diff.boxes
        total.scores += diff.scores
        total.selection_valid &= diff.selection_valid
        total.own_selection &= swaps == 0
        total.tie_swaps += swaps
        total.tie_substitutions += len(chosen) - len(np.intersect1d(chosen, own))
        total.labels_equal &= diff.labels_equal
        total.valid_equal &= diff.valid_equal
        total.other_label_or_validity += diff.other_label_or_validity
        total.notes += diff.notes
    return total


def _outputs_equal(a: Outputs, b: Outputs) -> bool:
    """The written file's outputs against the checked graph's: the same computation, so equal."""
    return all(np.array_equal(a[k], b[k]) for k in OUTPUTS)


def verify(path: str | Path, reference: Reference, threads: Sequence[int] = (1, 2)) -> ParityReport:
    """Check the file ``path`` against ``reference`` (the PyTorch model on its frames), one by one and batched.

    A reference serves several files (its float64 answers are computed once per ranking): the
    tolerances of each report rest on float32's drift at every choice the reference has compared.
    """
    path = Path(path)
    checked = checked_graph(path, path.with_name(f".{path.name}.{os.getpid()}.checked"))
    try:
        return _verify(path, checked, reference, threads)
    finally:
        checked.unlink(missing_ok=True)


def _verify(path: Path, checked: Path, reference: Reference, threads: Sequence[int]) -> ParityReport:
    frames, valid = reference.frames, reference.valid
    diffs = []
    for t in threads:
        diffs.append(compare_run(reference, run_onnx(checked, frames, valid, t, PROBE, per_frame=True)))
    batched = run_onnx(checked, frames, valid, threads[-1], PROBE)
    diffs.append(compare_run(reference, batched))
    written_equal = _outputs_equal(run_onnx(path, frames, valid, threads[-1]), batched)
    tol = reference.float32_errors.tolerances()  # float32's drift at every choice compared
    errors = Errors()
    for d in diffs:
        errors.update(d.errors)
    f32 = reference.float32_errors
    return ParityReport(
        frames=len(frames),
        threads=tuple(threads),
        reference="pytorch-float64",
        max_box_abs_diff_m=errors.box,
        max_score_abs_diff=errors.score,
        max_rank_score_abs_diff=errors.rank_score,
        pytorch_float32=(f32.rank_score, f32.box, f32.score),
        labels_equal=all(d.labels_equal for d in diffs),
        order_equal=all(d.own_selection for d in diffs),
        valid_equal=all(d.valid_equal for d in diffs),
        selection_valid=all(d.selection_valid for d in diffs),
        tie_swaps=max(d.tie_swaps for d in diffs),
        tie_substitutions=max(d.tie_substitutions for d in diffs),
        unmatched=max(d.mismatched(tol) for d in diffs),
        written_equals_checked=written_equal,
        problems=tuple(dict.fromkeys(note for d in diffs for note in d.notes))[:5],
        tolerance_box_m=tol.box,
        tolerance_score=tol.score,
        tolerance_rank_score=tol.rank_score,
        passed=bool(all(d.passed(tol) for d in diffs) and written_equal),
    )
