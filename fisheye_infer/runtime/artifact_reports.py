"""The records an exported file's metadata carries beside its interface (``artifact.ArtifactMeta``).

The export's parity reports (an fp32 file against PyTorch, a reduced-precision file against its fp32
file), how a file was quantized and how its int8 search chose, the TensorRT check's findings, and the
virtual cameras that stand a robot's cameras in for the training cameras.
"""

from __future__ import annotations

from typing import Any, Literal

from pydantic import BaseModel, ConfigDict

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry.virtual import VirtualCameraReport
from fisheye_infer.precision import MIN_TOP_MATCHED

__all__ = [
    "ParityReport",
    "ReducedParityReport",
    "Int8Search",
    "Int8Trial",
    "Quantization",
    "ReplayedChoice",
    "TensorRTFinding",
    "TensorRTReport",
    "VirtualCameras",
]


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class ReplayedChoice(_Model):
    """The reference file evaluated at the candidate's own top-k choice (its ranking step fed the
    candidate's indices): the candidate's numeric differences, with tie-breaking taken out."""

    top_matched_fraction: float  # of the reference's top-50 boxes at that choice, matched within 0.5 m and same label
    max_box_abs_diff_m: float  # position by position
    max_score_abs_diff: float
    labels_equal: bool


class ParityReport(_Model):
    """An fp32 file against the PyTorch model on the same frames, measured at export time.

    The graph is compared with the PyTorch model evaluated in float64 and may differ from it by at
    most a few times what PyTorch's own float32 evaluation does (``pytorch_float32``; the tolerances
    applied are recorded). Boxes are compared position by position at the graph's own top-k choice,
    which must be a top-k of its dense scores: ties broken otherwise than PyTorch float32 does are
    counted, not failed.
    """

    reference: Literal["pytorch-float64", "pytorch"] = "pytorch-float64"  # "pytorch": schema-1 files that did not say
    frames: int
    threads: tuple[int, ...]
    max_box_abs_diff_m: float
    max_score_abs_diff: float
    max_rank_score_abs_diff: float | None = None  # the dense scores before ranking (heatmap / class scores)
    pytorch_float32: tuple[float, float, float] | None = (
        None  # PyTorch float32's (dense score, box m, score) differences
    )
    labels_equal: bool
    order_equal: bool  # the graph chose exactly PyTorch float32's top k, in the same order
    valid_equal: bool
    selection_valid: bool | None = None  # the graph's choice is a top-k of its dense scores
    tie_swaps: int = 0  # positions whose proposal differs from PyTorch float32's choice (tied scores)
    tie_substitutions: int = 0  # proposals chosen from outside PyTorch float32's top k (tied scores)
    unmatched: int = 0  # boxes beyond tolerance or of another label / validity
    written_equals_checked: bool | None = None  # the written file (no ranking outputs) answers as the checked graph
    problems: tuple[str, ...] = ()
    tolerance_box_m: float
    tolerance_score: float
    tolerance_rank_score: float | None = None
    passed: bool


class ReducedParityReport(_Model):
    """A reduced-precision file (int8, fp16) against its fp32 file, both in ONNX Runtime, on the same frames.

    Not numeric agreement but the same detections: the share of the fp32 file's top-50 boxes the
    file finds again (``fisheye_infer.eval.top_match``), with its standard error over the frames and
    per band of the fp32 box's score; the file passes at ``min_top_matched``.
    """

    reference: Literal["fp32-onnx"] = "fp32-onnx"
    frames: int
    threads: tuple[int, ...]
    top_matched_fraction: float
    top_matched_standard_error: float | None = None  # None: schema-1 files that did not record it
    top_matched_by_score: dict[str, tuple[int, int]] | None = (
        None  # (matched, considered) per band of the fp32 box's score
    )
    min_top_matched: float  # the share the file had to reach
    match_radius_m: float  # a box is found again within this centre distance, with the same label
    unmatched: int  # fp32 top boxes not found again
    max_box_abs_diff_m: float  # over matched pairs
    max_score_abs_diff: float  # over matched pairs
    max_rank_score_abs_diff: float | None = None  # fp16: the dense scores before ranking
    labels_equal: bool  # position by position, at each file's own choice
    valid_equal: bool
    evaluated_with: str | None = None  # fp16: what ran the candidate (e.g. "onnxruntime-cpu")
    replayed: ReplayedChoice | None = None  # fp16: the fp32 file at the fp16 file's own top-k choice
    problems: tuple[str, ...] = ()
    passed: bool


_REDUCED_ONLY = (
    "top_matched_fraction",
    "top_matched_standard_error",
    "top_matched_by_score",
    "min_top_matched",
    "evaluated_with",
    "replayed",
)


def _parity_v1_to_v2(parity: dict[str, Any]) -> dict[str, Any]:
    """A schema-1 parity record (one report type for every file, unused fields null) in its schema-2 type."""
    if parity.get("reference") != "fp32-onnx":
        return {k: v for k, v in parity.items() if k not in _REDUCED_ONLY}
    reduced = {k: v for k, v in parity.items() if k in ReducedParityReport.model_fields and v is not None}
    reduced["match_radius_m"] = parity.get("tolerance_box_m", 0.5)
    reduced.setdefault("min_top_matched", MIN_TOP_MATCHED)  # the bar before it was recorded
    return reduced


class Int8Trial(_Model):
    """One int8 file the int8 search built and judged against the fp32 file (``export.int8_search``)."""

    #: start: the architecture's float modules; sensitivity: the start plus one candidate module float;
    #: float: the start plus the most sensitive modules; trunk: the image trunk alone in int8.
    step: Literal["start", "sensitivity", "float", "trunk"]
    scope: Literal["network", "trunk"]
    float_modules: tuple[str, ...]  # state-dict prefixes kept float32 (geometry and the like stay float anyway)
    int8_layers: int  # weighted layers in int8
    top_matched_fraction: float
    top_matched_standard_error: float
    passed: bool


class Int8Search(_Model):
    """How an int8 file's float32 modules were chosen: every trial, the one written, and what it gains."""

    trials: tuple[Int8Trial, ...]
    chosen: int | None  # index into ``trials``; None: none passed
    #: fp32 time / int8 time per frame on the exporting machine (median of alternated runs at ``threads``)
    speedup: float | None = None
    threads: int
    cpu: str  # the exporting machine's CPU, as ``fisheye_infer.tools.cpu`` names it
    seconds: float  # the search's wall time


class Quantization(_Model):
    """A reduced-precision file derived from a verified fp32 file: what was reduced and how."""

    mode: Literal["int8-qdq", "fp16"]
    scope: str
    calibration_frames: int = 0  # int8 only
    #: int8: the weights' bits. 7 keeps u8 x s8 pair sums within int16, so CPUs without VNNI compute what
    #: VNNI computes (``WEIGHT_BITS``); None in int8 files written before it was recorded (8 bits).
    weight_bits: Literal[7, 8] | None = None
    #: int8: the modules (state-dict prefixes) kept float32 beyond what every int8 file keeps float.
    float_modules: tuple[str, ...] = ()
    search: Int8Search | None = None  # int8 written by the search (``fisheye-infer export --int8`` alone)


class TensorRTFinding(_Model):
    """One thing TensorRT's ONNX parser refuses (``error``) or handles in a way worth knowing (``note``)."""

    severity: Literal["error", "note"]
    node: str = ""  # node name; empty for a finding about the whole graph
    op_type: str = ""
    message: str


class TensorRTReport(_Model):
    """The static check of a graph against TensorRT's ONNX parser limits (``export.tensorrt_check``).

    ``compatible`` is False when any finding is an error. The check reads the graph only: no
    TensorRT is needed, and passing it is evidence that the parser accepts the file, not a
    TensorRT build.
    """

    target: str
    compatible: bool
    findings: tuple[TensorRTFinding, ...] = ()

    def summary(self, limit: int = 3) -> str:
        """One line: the verdict, the error count, and the first ``limit`` errors (else notes)."""
        errors = [f for f in self.findings if f.severity == "error"]
        notes = len(self.findings) - len(errors)
        head = f"TensorRT ONNX parser ({self.target}): "
        if not errors:
            return head + f"compatible ({notes} note(s))"
        shown = "; ".join(f"{f.node} ({f.op_type}): {f.message}" if f.node else f.message for f in errors[:limit])
        more = f"; and {len(errors) - limit} more" if len(errors) > limit else ""
        return head + f"NOT compatible, {len(errors)} error(s): {shown}{more}"


class VirtualCameras(_Model):
    """The robot's cameras standing in for the training cameras ([`virtual`][fisheye_infer.geometry.virtual]).

    The file's ``rig``, ``cameras`` and ``image_size`` are the robot's (its cameras in the model's slot order,
    images padded to the largest); the network and its geometry tables are those of ``training_rig``.
    """

    training_rig: Rig
    depth_m: float | None = None  # None: rotation compensated, translation ignored
    unseen_fill: float  # grey level of training pixels the robot camera does not see
    cameras: tuple[VirtualCameraReport, ...]
