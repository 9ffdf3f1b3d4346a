"""The metadata an exported ONNX file carries: one JSON document, validated, versioned.

Everything a runtime must know to feed the graph and read its outputs travels inside the
``.onnx`` file under the ``metadata_props`` key ``fisheye_infer``: architecture, classes,
camera names and order, image size, colour order and normalisation, box layout and frame,
score semantics, the full rig with its hash, the tools that exported it, and the parity
report of the export. ``Detector`` reads it through ONNX Runtime (no ``onnx`` import needed)
and refuses files without it, with a schema version it does not know, or with a rig whose
content does not match its recorded hash.
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Final, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ArtifactError
from fisheye_infer.geometry.kinds import GeometryParams
from fisheye_infer.geometry.virtual import VirtualCameraReport
from fisheye_infer.precision import MIN_TOP_MATCHED

__all__ = [
    "ARTIFACT_SCHEMA_VERSION",
    "METADATA_KEY",
    "READABLE_SCHEMA_VERSIONS",
    "INPUT_IMAGES",
    "INPUT_CAMERA_VALID",
    "OUTPUTS",
    "RANKING_OUTPUTS",
    "ArtifactMeta",
    "Normalisation",
    "ParityReport",
    "ReducedParityReport",
    "Int8Search",
    "Int8Trial",
    "Quantization",
    "ReplayedChoice",
    "TensorRTFinding",
    "TensorRTReport",
    "VirtualCameras",
    "inspection_session",
    "parse_meta",
    "read_meta",
]

ARTIFACT_SCHEMA_VERSION: Final = 3
#: Schema versions this runtime reads: 1 and 2 are migrated on reading (``ArtifactMeta``).
READABLE_SCHEMA_VERSIONS: Final = (1, 2, 3)
METADATA_KEY = "fisheye_infer"
INPUT_IMAGES = "images"  # uint8 (B, N, H, W, 3) in the colour order below
INPUT_CAMERA_VALID = "camera_valid"  # bool (B, N): False zeroes that camera's features
OUTPUTS = ("boxes", "scores", "labels", "valid")  # (B, K, 7) f32, (B, K) f32, (B, K) i64, (B, K) bool
#: The dense scores a detector ranks (B, M) f32 and the K indices it chooses (B, K) i64. Only the
#: graph that the export check runs has them; a written file's outputs are ``OUTPUTS``.
RANKING_OUTPUTS = ("rank_scores", "rank_indices")


class _Model(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


class Normalisation(_Model):
    """``(x - mean[c]) / std[c]`` per input channel c, in the input's colour order.

    The official Fisheye3DOD models apply the RGB-ordered ImageNet statistics to BGR data;
    the numbers here are listed in input channel order, so that is explicit.
    """

    mean: tuple[float, float, float]
    std: tuple[float, float, float]


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


class ArtifactMeta(_Model):
    """The metadata document an exported file carries; reading a schema-1 or -2 document migrates it.

    Attributes:
        schema_version (Literal[3]): Version of this document's schema.
        architecture (str): The model's architecture (``fisheye_bevdet``, ``fisheye_petr``).
        model_id (str): Architecture + rig hash + checkpoint digest: names this exact file's behaviour.
        classes (tuple[str, ...]): Class names, in label order.
        cameras (tuple[str, ...]): Camera names, in the order of the images input.
        image_size (tuple[int, int]): (width, height) of every input image, pixels.
        colour_order (Literal['BGR', 'RGB']): Channel order of the images input.
        normalisation (Normalisation): Per-channel mean and standard deviation the images are normalised with.
        num_boxes (int): Boxes the graph returns per frame.
        box_layout (tuple[str, ...]): The meaning of each of a box's values.
        box_frame (str): The boxes' coordinate frame and units, in words.
        score_semantics (str): What a score means, in words.
        valid_semantics (str): What the ``valid`` output marks, in words.
        rig (Rig): The camera rig whose geometry is baked into the graph.
        rig_hash (str): Hash of ``rig``; a mismatch means the file was altered.
        geometry (GeometryParams): The parameters the geometry tables were computed with.
        geometry_source (Literal['rig', 'checkpoint']): Whether the tables come from the rig or the checkpoint.
        geometry_initializers (tuple[str, ...]): Names of the graph initializers holding the geometry tables.
        checkpoint_sha256 (str | None): Digest of the checkpoint exported.
        tools (dict[str, str]): Versions of the tools that wrote the file.
        parity (ParityReport | ReducedParityReport | None): The export's check against PyTorch.
        quantization (Quantization | None): How the file was quantized (None: fp32).
        tensorrt (TensorRTReport | None): The TensorRT check's record, where one ran.
        virtual_cameras (VirtualCameras | None): The front end that resamples a robot's cameras into the
            model's, where the file has one.
    """

    schema_version: Literal[3] = ARTIFACT_SCHEMA_VERSION
    architecture: str
    model_id: str = Field(description="architecture + rig hash + checkpoint digest: names this exact file's behaviour")
    classes: tuple[str, ...]
    cameras: tuple[str, ...]
    image_size: tuple[int, int] = Field(description="(width, height) of every input image")
    colour_order: Literal["BGR", "RGB"] = "BGR"
    normalisation: Normalisation
    num_boxes: int
    box_layout: tuple[str, ...] = ("x", "y", "z_bottom", "l", "w", "h", "yaw")
    box_frame: str = "lidar: x forward, y left, z up (m); yaw about +z, 0 along +x, counter-clockwise"
    score_semantics: str
    valid_semantics: str = (
        "box centre inside the official post_center_range; the official output set is exactly the valid boxes"
    )
    rig: Rig
    rig_hash: str
    geometry: Annotated[GeometryParams, Field(discriminator="kind")]
    geometry_source: Literal["rig", "checkpoint"] = "rig"
    geometry_initializers: tuple[str, ...] = ()
    checkpoint_sha256: str | None = None
    tools: dict[str, str] = Field(default_factory=dict)
    parity: Annotated[ParityReport | ReducedParityReport, Field(discriminator="reference")] | None = None
    quantization: Quantization | None = None
    tensorrt: TensorRTReport | None = None  # files written before the check have none
    virtual_cameras: VirtualCameras | None = None  # a front end resamples the robot's cameras into the model's

    @model_validator(mode="before")
    @classmethod
    def _migrate(cls, data: Any) -> Any:
        """Schema 1 -> 2: the parity record takes the type of the file it describes (fp32 or reduced).
        2 -> 3: the int8 search's record and float modules, absent from older files, are added."""
        if isinstance(data, dict) and data.get("schema_version") == 1:
            data = {**data, "schema_version": 2}
            if isinstance(data.get("parity"), dict):
                data["parity"] = _parity_v1_to_v2(data["parity"])
        if isinstance(data, dict) and data.get("schema_version") == 2:
            data = {**data, "schema_version": 3}
        return data

    def check(self) -> ArtifactMeta:
        """Check what a reader can verify: the rig matches its hash and the camera list.

        Returns:
            ArtifactMeta: This document, unchanged.

        Raises:
            ArtifactError: The rig, the camera list or the virtual cameras disagree.
        """
        if self.rig.hash != self.rig_hash:
            raise ArtifactError(
                f"rig_hash: metadata says {self.rig_hash}, the embedded rig hashes to {self.rig.hash}; "
                "the file was altered"
            )
        if tuple(self.rig.names) != self.cameras:
            raise ArtifactError(
                f"cameras: metadata lists {', '.join(self.cameras)}, the embedded rig has {', '.join(self.rig.names)}"
            )
        if self.virtual_cameras is not None and len(self.virtual_cameras.training_rig) != len(self.cameras):
            raise ArtifactError(
                f"virtual_cameras: {len(self.virtual_cameras.training_rig)} training cameras for "
                f"{len(self.cameras)} cameras"
            )
        return self

    @property
    def training_rig(self) -> Rig:
        """The rig the network's geometry tables were computed for: the training rig behind virtual cameras."""
        return self.rig if self.virtual_cameras is None else self.virtual_cameras.training_rig

    def camera_sizes(self) -> tuple[tuple[int, int], ...]:
        """(width, height) of each camera's images, in camera order: the rig's own sizes behind virtual cameras
        (padded to ``image_size`` in the graph's input), ``image_size`` for every camera otherwise."""
        if self.virtual_cameras is None:
            return tuple(self.image_size for _ in self.cameras)
        return tuple((c.model.width, c.model.height) for c in self.rig.cameras)


def parse_meta(document: str | None, source: str = "model") -> ArtifactMeta:
    """Validate the JSON document stored under ``METADATA_KEY``."""
    if document is None:
        raise ArtifactError(f"{source}: no '{METADATA_KEY}' metadata; export the model with 'fisheye-infer export'")
    try:
        import json

        raw = json.loads(document)
    except (ValueError, RecursionError) as exc:  # RecursionError: nested too deep
        raise ArtifactError(f"{source}: '{METADATA_KEY}' metadata is not JSON ({str(exc)[:200]})") from exc
    version = raw.get("schema_version") if isinstance(raw, dict) else None
    if version not in READABLE_SCHEMA_VERSIONS:
        raise ArtifactError(
            f"{source}: metadata schema_version {repr(version)[:40]} is not supported by this fisheye-infer "
            f"(it reads {', '.join(map(str, READABLE_SCHEMA_VERSIONS[:-1]))} and {READABLE_SCHEMA_VERSIONS[-1]})"
        )
    try:
        return ArtifactMeta.model_validate(raw).check()
    except ValidationError as exc:
        fields = "; ".join(f"{'.'.join(str(x) for x in e['loc'])}: {e['msg']}" for e in exc.errors()[:5])
        raise ArtifactError(f"{source}: invalid metadata: {fields}") from None


def inspection_session(path: str | Path) -> Any:
    """An unoptimised CPU ``onnxruntime.InferenceSession`` of ``path``: enough to read its metadata
    and interface without the cost of graph optimisation."""
    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise ArtifactError(f"model {path}: no such file")
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    try:
        return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    except Exception as exc:  # ORT raises its own untyped errors for unreadable files
        raise ArtifactError(f"model {path}: ONNX Runtime cannot load it ({exc})") from exc


def read_meta(path: str | Path) -> ArtifactMeta:
    """Read the metadata of an exported ONNX file with ONNX Runtime, without building a Detector.

    Args:
        path (str | Path): An ONNX file written by ``fisheye-infer export``.

    Returns:
        ArtifactMeta: The checked metadata, migrated to the current schema.

    Raises:
        ArtifactError: The file is missing, ONNX Runtime cannot load it, or its fisheye-infer metadata is
            absent or invalid.

    Examples:
        ```python
        meta = read_meta("model.onnx")
        print(meta.architecture, meta.classes, meta.image_size, meta.rig.names)
        ```
    """
    session = inspection_session(path)
    return parse_meta(session.get_modelmeta().custom_metadata_map.get(METADATA_KEY), source=f"model {path}")
