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

from pydantic import Field, ValidationError, model_validator

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ArtifactError
from fisheye_infer.geometry.kinds import GeometryParams
from fisheye_infer.runtime.artifact_reports import (
    Int8Search,
    Int8Trial,
    ParityReport,
    Quantization,
    ReducedParityReport,
    ReplayedChoice,
    TensorRTFinding,
    TensorRTReport,
    VirtualCameras,
    _Model,
    _parity_v1_to_v2,
)

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


class Normalisation(_Model):
    """``(x - mean[c]) / std[c]`` per input channel c, in the input's colour order.

    The official Fisheye3DOD models apply the RGB-ordered ImageNet statistics to BGR data;
    the numbers here are listed in input channel order, so that is explicit.
    """

    mean: tuple[float, float, float]
    std: tuple[float, float, float]


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
