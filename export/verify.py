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
"""

from __future__ import annotations

import contextlib
import copy
import os
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import onnx
import onnxruntime as ort
import torch
from torch import nn

from fisheye_infer.errors import ExportError
from fisheye_infer.models.ranking import TopK, replay_ranking
from fisheye_infer.runtime.artifact import INPUT_CAMERA_VALID, INPUT_IMAGES, OUTPUTS, RANKING_OUTPUTS, ParityReport
from fisheye_infer.runtime.box_geometry import box_diff

from .graph import save_model, with_outputs

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

FLOOR_BOX_M = 1e-3
FLOOR_SCORE = 1e-4
#: How much further from float64 than PyTorch float32 the graph may be.
SLACK = 4.0

Outputs = dict[str, np.ndarray]
#: What the checked graph outputs: the file's outputs, then the ranking values.
PROBE = OUTPUTS + RANKING_OUTPUTS


@dataclass
class Errors:
    """Largest differences from the float64 reference (dense scores, boxes in m, scores)."""

    rank_score: float = 0.0
    box: float = 0.0
    score: float = 0.0

    def update(self, other: Errors) -> None:
        self.rank_score = max(self.rank_score, other.rank_score)
        self.box = max(self.box, other.box)
        self.score = max(self.score, other.score)

    def tolerances(self) -> Errors:
        """What a graph may differ by, given that PyTorch float32 differs by ``self``."""
        return Errors(
            max(FLOOR_SCORE, SLACK * self.rank_score),
            max(FLOOR_BOX_M, SLACK * self.box),
            max(FLOOR_SCORE, SLACK * self.score),
        )


@dataclass
class RunDiff:
    """One ONNX Runtime run (a batch of frames) against the float64 reference."""

    errors: Errors = field(default_factory=Errors)
    boxes: list[np.ndarray] = field(default_factory=list)  # per frame: box difference per position
    scores: list[np.ndarray] = field(default_factory=list)
    selection_valid: bool = True  # the graph's choice is a top-k of its own dense scores
    own_selection: bool = True  # ... and it is PyTorch float32's own choice, position by position
    tie_swaps: int = 0  # positions whose index differs from PyTorch float32's choice
    tie_substitutions: int = 0  # chosen indices outside PyTorch float32's top K
    labels_equal: bool = True
    valid_equal: bool = True
    other_label_or_validity: int = 0  # boxes
    notes: list[str] = field(default_factory=list)

    def mismatched(self, tol: Errors) -> int:
        """Boxes beyond tolerance, or of another label or validity."""
        off = sum(int(np.count_nonzero((b > tol.box) | (s > tol.score))) for b, s in zip(self.boxes, self.scores))
        return off + self.other_label_or_validity

    def passed(self, tol: Errors) -> bool:
        return self.errors.rank_score <= tol.rank_score and self.selection_valid and self.mismatched(tol) == 0


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
    options = ort.SessionOptions()
    options.intra_op_num_threads = threads
    options.inter_op_num_threads = 1
    options.log_severity_level = 3
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    batches = [slice(i, i + 1) for i in range(len(images))] if per_frame else [slice(None)]
    runs = [session.run(list(outputs), {INPUT_IMAGES: images[b], INPUT_CAMERA_VALID: valid[b]}) for b in batches]
    return {name: np.concatenate([r[k] for r in runs]) for k, name in enumerate(outputs)}


@dataclass(frozen=True)
class _Exact:
    out: Outputs  # the float64 model's outputs at a replayed ranking
    own_dense: np.ndarray  # (M,) the float64 model's own dense scores
    problem: str  # "" when the replayed indices are a top-k of the replayed scores


class _Head:
    """A model's ranking head, with the inputs it received for each frame in one full run.

    The trunk runs once per frame; every replay of a ranking runs the head alone, and of the head only
    what follows the ranking (``_BeforeRanking``): PETR's decoder, which comes before it, runs once.
    """

    def __init__(self, model: nn.Module, frames: np.ndarray, valid: np.ndarray) -> None:
        self.module = _ranking_head(model)
        self.inputs: list[tuple[tuple, dict]] = []
        self.before_ranking: list[_BeforeRanking] = []
        hook = self.module.register_forward_pre_hook(
            lambda _, args, kwargs: self.inputs.append((args, kwargs)), with_kwargs=True
        )
        try:
            self.outputs = []
            for i in range(len(frames)):
                with _BeforeRanking(self.module) as before:
                    self.outputs.append(run_torch(model, frames[i : i + 1], valid[i : i + 1]))
                self.before_ranking.append(before)
        finally:
            hook.remove()

    @torch.no_grad()
    def replay(self, frame: int, dense: np.ndarray, indices: np.ndarray) -> _Exact:
        args, kwargs = self.inputs[frame]
        dtype = next(self.module.parameters()).dtype
        d = torch.from_numpy(np.ascontiguousarray(dense[None])).to(dtype)
        chosen = torch.from_numpy(np.ascontiguousarray(indices[None], np.int64))
        with replay_ranking(self.module, d, chosen) as step, self.before_ranking[frame].reused():
            out = self.module(*args, **kwargs)
        if step.own_dense is None:
            raise ExportError("the parity check's replay of the ranking produced no dense scores")
        return _Exact({k: out[k].cpu().numpy() for k in PROBE}, step.own_dense.cpu().numpy()[0], step.problem)


class _BeforeRanking:
    """What a ranking head computes before its ranking step, recorded in one run and handed back in replays.

    A replay changes the ranking's scores and choice only, so every submodule that returned before the
    ranking step first read its scores gives the same output again. Recorded: the outermost of those
    called once in the run (a module called several times keeps running); ``reused()`` makes each return
    a copy of its recorded output instead of running.
    """

    def __init__(self, head: nn.Module) -> None:
        self.head = head
        (self.step,) = [m for m in head.modules() if isinstance(m, TopK)]
        self.outputs: dict[str, object] = {}
        self.calls: dict[str, int] = {}
        self._ranked = False

    def __enter__(self) -> _BeforeRanking:
        (step_name,) = [name for name, m in self.head.named_modules() if m is self.step]
        parts = step_name.split(".")
        owners = {".".join(parts[:i]) for i in range(len(parts) + 1)}  # the step and the modules that hold it
        self._hooks = [
            m.register_forward_hook(self._keep(name)) for name, m in self.head.named_modules() if name not in owners
        ]
        dense = self.step.dense

        def ranked(scores: torch.Tensor) -> torch.Tensor:
            self._ranked = True
            return dense(scores)

        self.step.dense = ranked  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        for hook in self._hooks:
            hook.remove()
        del self.step.dense  # the class's method again
        once = {name for name, count in self.calls.items() if count == 1 and name in self.outputs}
        outermost = {n for n in once if not any(n.startswith(f"{m}.") for m in once)}
        self.outputs = {n: v for n, v in self.outputs.items() if n in outermost}

    def _keep(self, name: str) -> Callable[[nn.Module, object, object], None]:
        def hook(module: nn.Module, args: object, output: object) -> None:
            self.calls[name] = self.calls.get(name, 0) + 1
            if not self._ranked:
                self.outputs[name] = _copy(output)  # as returned, whatever the run does with it afterwards

        return hook

    @contextlib.contextmanager
    def reused(self) -> Iterator[None]:
        modules = dict(self.head.named_modules())
        for name, output in self.outputs.items():
            modules[name].forward = lambda *_, _out=output, **__: _copy(_out)
        try:
            yield
        finally:
            for name in self.outputs:
                del modules[name].forward


def _copy(value: object) -> object:
    """Tensors cloned (a replay may write into what a module returns), containers rebuilt, the rest as is."""
    if isinstance(value, torch.Tensor):
        return value.clone()
    if isinstance(value, tuple) and hasattr(value, "_fields"):  # a named tuple
        named: Any = type(value)
        return named(*[_copy(v) for v in value])
    if isinstance(value, (tuple, list)):
        return type(value)([_copy(v) for v in value])
    if isinstance(value, dict):
        return {k: _copy(v) for k, v in value.items()}
    return value


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
        self.single = _Head(model, frames, valid)
        self.double = _Head(copy.deepcopy(model).double().eval(), frames, valid)
        self.float32 = self.single.outputs
        self._cache: dict[tuple[int, bytes, bytes], _Exact] = {}
        self.float32_errors = Errors()
        for f, out in enumerate(self.float32):
            self.float32_errors.update(self.diff(f, out)[0].errors)

    def __len__(self) -> int:
        return len(self.float32)

    def exact(self, frame: int, dense: np.ndarray, indices: np.ndarray) -> _Exact:
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


def _ranking_head(model: nn.Module) -> nn.Module:
    """The child of ``model`` that holds its ranking step and returns the detector's outputs."""
    for _, child in model.named_children():
        if any(isinstance(m, TopK) for m in child.modules()):
            return child
    raise ValueError(f"{type(model).__name__} has no ranking step")


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


def checked_graph(path: str | Path, out: str | Path) -> Path:
    """Write the file ``path`` with its ranking values (``RANKING_OUTPUTS``) as extra outputs to ``out``."""
    model = onnx.load(str(path))
    return save_model(
        with_outputs(model, {"rank_scores": onnx.TensorProto.FLOAT, "rank_indices": onnx.TensorProto.INT64}), out
    )


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
