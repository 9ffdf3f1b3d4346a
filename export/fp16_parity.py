"""Evidence for an fp16 file: its detections against the verified fp32 file's, on the same frames.

Two comparisons, by default both in ONNX Runtime's CPU execution provider (which runs a float16
graph: values between nodes stay float16 as in the file; a node it has no float16 kernel for runs
its float32 kernel between Casts that ORT inserts). ``candidate_providers`` runs the candidate
file elsewhere instead (a GPU's CUDA provider, where it will run), the fp32 reference staying on
the CPU:

1. at each file's own top-k choice, the criterion shared with int8: the share of the fp32
   file's top-50 boxes found again within 0.5 m with the same label (``fisheye_infer.eval.top_match``);
2. at the fp16 file's own choice, replayed in the fp32 file (its ``TopK`` replaced by the fp16
   file's indices): box and score differences position by position. When the fp32 scores tie
   (a saturated heatmap has hundreds of cells at exactly 1.0), which tied cells a top-k keeps is
   not defined, any perturbation changes it, and comparison 1 then measures tie-breaking, not
   float16; comparison 2 does not, and the report says how many scores tie.

The PyTorch models are not the fallback: they cast images with ``images.to(torch.float32)``,
so ``model.half()`` does not run them as they are.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort

from fisheye_infer.errors import ExportError
from fisheye_infer.eval.top_match import MATCH_RADIUS_M, top_matched
from fisheye_infer.precision import MIN_TOP_MATCHED
from fisheye_infer.runtime.artifact import (
    INPUT_CAMERA_VALID,
    INPUT_IMAGES,
    OUTPUTS,
    RANKING_OUTPUTS,
    ReducedParityReport,
    ReplayedChoice,
)
from fisheye_infer.runtime.box_geometry import box_diff
from fisheye_infer.runtime.denormals import flushed_denormals
from fisheye_infer.runtime.session import Provider, open_session, provider_name, resolve_providers, session_options

from .graph import with_outputs

__all__ = ["evaluated_with", "fp16_parity", "replay_choice"]

_SCORES, _INDICES = RANKING_OUTPUTS
Outputs = dict[str, np.ndarray]


def replay_choice(model: onnx.ModelProto) -> onnx.ModelProto:
    """A copy of ``model`` whose ranking ``TopK`` is replaced by a graph input ``rank_indices``:
    the values it kept are gathered from the dense scores at the indices given."""
    out = onnx.ModelProto()
    out.CopyFrom(model)
    graph = out.graph
    position = next((i for i, n in enumerate(graph.node) if _INDICES in n.output), None)
    if position is None or graph.node[position].op_type != "TopK":
        raise ExportError(f"fp16: the graph has no TopK producing '{_INDICES}'; cannot replay a ranking")
    topk = graph.node[position]
    axis = next((a.i for a in topk.attribute if a.name == "axis"), -1)
    replacement = (
        [
            onnx.helper.make_node(
                "GatherElements", [topk.input[0], _INDICES], [topk.output[0]], name=f"{topk.name}_replayed", axis=axis
            )
        ]
        if topk.output[0]
        else []
    )
    del graph.node[position]
    for node in reversed(replacement):
        graph.node.insert(position, node)
    graph.input.append(onnx.helper.make_tensor_value_info(_INDICES, onnx.TensorProto.INT64, ["batch", None]))
    return out


def _session(
    model: onnx.ModelProto, threads: int, providers: Sequence[Provider] = ("CPUExecutionProvider",)
) -> ort.InferenceSession:
    return open_session(model.SerializeToString(), session_options(threads), providers, "fp16 parity")


def evaluated_with(providers: Sequence[Provider]) -> str:
    """``onnxruntime-cpu``, ``onnxruntime-cuda``, ...: the first (preferred) provider's short name."""
    return f"onnxruntime-{provider_name(providers[0]).removesuffix('ExecutionProvider').lower()}"


def _run(session: ort.InferenceSession, frames: np.ndarray, extra: np.ndarray | None = None) -> Outputs:
    """One frame at a time (batch-1 memory), every output, concatenated."""
    names = [o.name for o in session.get_outputs()]
    valid = np.ones(frames.shape[:2], bool)
    runs = []
    with flushed_denormals():
        for i in range(len(frames)):
            feed = {INPUT_IMAGES: frames[i : i + 1], INPUT_CAMERA_VALID: valid[i : i + 1]}
            if extra is not None:
                feed[_INDICES] = extra[i : i + 1]
            runs.append(session.run(names, feed))
    return {name: np.concatenate([r[k] for r in runs]) for k, name in enumerate(names)}


def _with_ranking(model: onnx.ModelProto) -> onnx.ModelProto:
    types = {v.name: v.type.tensor_type.elem_type for v in onnx.shape_inference.infer_shapes(model).graph.value_info}
    return with_outputs(model, {_SCORES: types.get(_SCORES, onnx.TensorProto.FLOAT), _INDICES: onnx.TensorProto.INT64})


def _ties(dense: np.ndarray, k: int) -> int:
    """The most scores of one frame equal to its k-th largest: more than one means the top-k is not unique."""
    kth = np.sort(dense, axis=1)[:, -k]
    return int(max(np.count_nonzero(d == s) for d, s in zip(dense, kth)))


def fp16_parity(
    fp32_path: str | Path,
    fp16_path: str | Path,
    frames: np.ndarray,
    threads: int = 2,
    min_fraction: float = MIN_TOP_MATCHED,
    candidate_providers: Sequence[Provider] = ("CPUExecutionProvider",),
) -> ReducedParityReport:
    """The fp16 file against the fp32 file on ``frames`` (F, N, H, W, 3) uint8; see the module docstring.

    Passes when at least ``min_fraction`` of the fp32 top-50 boxes are found again (comparison 1).
    ``fp16_path`` may be any file with the fp32 file's interface (the fp32 file itself, run in
    ``candidate_providers``, measures what a GPU provider's arithmetic changes).
    """
    fp32 = onnx.load(str(fp32_path))
    providers = [candidate_providers] if isinstance(candidate_providers, str) else list(candidate_providers)
    if not providers:
        raise ExportError("fp16: candidate_providers: expected at least one provider")
    where = evaluated_with(providers)
    try:
        session = _session(
            _with_ranking(onnx.load(str(fp16_path))), threads, resolve_providers(providers)
        )  # no silent fallback to the CPU
        half = _run(session, frames)
    except Exception as exc:  # ORT's errors are untyped
        raise ExportError(f"fp16: ONNX Runtime ({where}) cannot run {fp16_path} ({exc}); no parity") from exc
    full = _run(_session(_with_ranking(fp32), threads), frames)
    replayed = _run(_session(replay_choice(fp32), threads), frames, half[_INDICES])
    ref, cand, at_choice = ([o[k] for k in OUTPUTS] for o in (full, half, replayed))
    kept = top_matched(ref, cand)
    at_own_choice = top_matched(at_choice, cand)
    k = half[_INDICES].shape[1]
    ties = _ties(full[_SCORES], k)
    problems = (
        (
            f"the fp32 file's dense scores tie: up to {ties} of them equal the {k}-th largest, so which tied cells its "
            f"top-{k} keeps is not defined; the replayed comparison measures float16 alone",
        )
        if ties > 1
        else ()
    )
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
        max_rank_score_abs_diff=float(np.abs(full[_SCORES].astype(np.float64) - half[_SCORES]).max()),
        labels_equal=bool(np.array_equal(ref[2], cand[2])),
        valid_equal=bool(np.array_equal(ref[3], cand[3])),
        passed=kept.fraction >= min_fraction,
        evaluated_with=evaluated_with(session.get_providers()),
        problems=problems,
        replayed=ReplayedChoice(
            top_matched_fraction=at_own_choice.fraction,
            max_box_abs_diff_m=float(box_diff(at_choice[0], cand[0]).max()),
            max_score_abs_diff=float(np.abs(at_choice[1].astype(np.float64) - cand[1]).max()),
            labels_equal=bool(np.array_equal(at_choice[2], cand[2])),
        ),
    )
