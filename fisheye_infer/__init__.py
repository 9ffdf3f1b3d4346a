"""fisheye-infer: run surround-view fisheye 3D object detectors with ONNX Runtime.

The core (this package) needs numpy, onnxruntime, OpenCV, simplejpeg and pydantic only: camera models,
rigs, the geometry tables the detectors are built on, and ``Detector``, which runs an exported
model and returns ``Detections``. ``fisheye_infer.models`` and
``fisheye_infer.export`` need the ``[export]`` extra (torch, onnx); ``fisheye_infer.service``
needs ``[serve]``; its Ray Serve deployment and ``fisheye_infer.batch`` (Ray Data) need ``[ray]``;
``fisheye_infer.triton.TritonDetector`` needs ``[triton]``. Importing this package loads none of them.
"""

from fisheye_infer._version import __version__
from fisheye_infer.camera import CameraModel, Equidistant, KannalaBrandt, OCamModel, Pinhole
from fisheye_infer.camera_fit import OCamFit, fit_ocam_from_kb
from fisheye_infer.detections import Detections
from fisheye_infer.detector import Detector, DetectorInfo
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
from fisheye_infer.nms import NmsConfig
from fisheye_infer.rig import FISHEYE3DOD_CAMERAS, Rig, RigCamera, default_rig, resolve_rig

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
    "InferenceError",
    "KannalaBrandt",
    "NmsConfig",
    "OCamFit",
    "OCamModel",
    "OptionError",
    "ParityError",
    "Pinhole",
    "Rig",
    "RigCamera",
    "RigError",
    "default_rig",
    "fit_ocam_from_kb",
    "resolve_rig",
]
