"""fisheye-infer: run surround-view fisheye 3D object detectors with ONNX Runtime.

The core (this package) needs numpy, onnxruntime, OpenCV, simplejpeg, pydantic and scipy (the
tracker's assignment solver) only. Its subpackages follow the data path: ``cameras`` (camera models,
rigs) -> ``geometry`` (the tables the detectors are built on) -> ``runtime`` (``Detector``: an
exported file and frames in, ``Detections`` out) -> ``tracking`` (``Tracker``: tracks over a stream)
-> ``eval`` (FDS, mAP and the tracking metrics); beside it ``deploy`` (Ray Data, Triton), ``scenes``
(synthetic frames and sequences), ``tools`` (bench, viz), ``commands`` (the CLI) and ``precision``
(the int8/fp16 policy).
``fisheye_infer.models`` and ``fisheye_infer.export`` need the ``[export]`` extra (torch, onnx);
``fisheye_infer.service`` needs ``[serve]``; its Ray Serve deployment and
``fisheye_infer.deploy.ray_batch`` (Ray Data) need ``[ray]``; ``fisheye_infer.deploy.triton.TritonDetector``
needs ``[triton]``. Importing this package loads none of them.
"""

from fisheye_infer import _moved
from fisheye_infer._version import __version__
from fisheye_infer.cameras.camera_models import (
    CameraModel,
    DistortedPinhole,
    DoubleSphere,
    Equidistant,
    ExtendedUnified,
    KannalaBrandt,
    OCamModel,
    Omnidirectional,
    Pinhole,
)
from fisheye_infer.cameras.ocam_fit import OCamFit, fit_ocam, fit_ocam_from_kb
from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS, Rig, RigCamera, default_rig, resolve_rig
from fisheye_infer.errors import (
    ArtifactError,
    CameraModelError,
    CheckpointError,
    ConfigError,
    DatasetError,
    ExportError,
    FisheyeInferError,
    FrameError,
    InferenceError,
    OptionError,
    ParityError,
    RigError,
)
from fisheye_infer.runtime.detections import Detections
from fisheye_infer.runtime.detector import Detector, DetectorInfo
from fisheye_infer.runtime.nms import NmsConfig
from fisheye_infer.tracking import GreedyTracker, Tracker, TrackerConfig, Tracks

_moved.install()

__all__ = [
    "__version__",
    "ArtifactError",
    "CameraModel",
    "CameraModelError",
    "CheckpointError",
    "ConfigError",
    "DatasetError",
    "Detections",
    "Detector",
    "DetectorInfo",
    "Equidistant",
    "ExportError",
    "FISHEYE3DOD_CAMERAS",
    "FisheyeInferError",
    "FrameError",
    "GreedyTracker",
    "InferenceError",
    "KannalaBrandt",
    "DistortedPinhole",
    "DoubleSphere",
    "ExtendedUnified",
    "Omnidirectional",
    "NmsConfig",
    "OCamFit",
    "OCamModel",
    "OptionError",
    "ParityError",
    "Pinhole",
    "Rig",
    "RigCamera",
    "RigError",
    "Tracker",
    "TrackerConfig",
    "Tracks",
    "default_rig",
    "fit_ocam",
    "fit_ocam_from_kb",
    "resolve_rig",
]
