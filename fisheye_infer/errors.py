"""One exception tree for everything fisheye-infer raises on purpose.

    FisheyeInferError
     ├── CameraModelError   a calibration file or camera parameter is malformed       (ValueError)
     ├── RigError           a rig is incomplete or inconsistent (camera, field named) (ValueError)
     ├── ConfigError        a model configuration or geometry parameters are refused  (ValueError)
     ├── CheckpointError    a checkpoint does not fit the model (keys named)
     ├── ExportError        an export cannot be carried out
     │    └── ParityError   the exported graph disagrees with PyTorch beyond tolerance
     ├── ArtifactError      an ONNX file lacks or has wrong fisheye-infer metadata or graph
     ├── FrameError         an input frame is unusable (camera and field named)       (ValueError)
     ├── OptionError        a detect option has the wrong type or is out of range     (ValueError)
     ├── DatasetError       a Fisheye3DOD folder is missing or malformed              (ValueError)
     ├── BagError           a recorded bag cannot be read (the bag and the problem named) (ValueError)
     └── InferenceError     ONNX Runtime failed while running a valid frame

Messages name the camera or field and say what was expected and what was received,
so a user can act on them without reading a traceback. The errors about a value the caller
passed are also ``ValueError`` subclasses. Foreign exceptions are translated where they enter (ONNX
Runtime's in ``session.map_ort_errors``, torch's and onnx's in the exporter), and the tree is
mapped once per front end: ``fisheye_infer.cli.main`` prints the message and exits 1,
``fisheye_infer.service.errors.error_response`` gives each class its HTTP status. A plain
``ValueError`` or ``TypeError`` from a building block (a numpy array of the wrong shape passed to
a geometry function) is a programming error, not a refusal of user input.
"""

from __future__ import annotations

__all__ = [
    "FisheyeInferError",
    "CameraModelError",
    "RigError",
    "ConfigError",
    "CheckpointError",
    "ExportError",
    "ParityError",
    "ArtifactError",
    "FrameError",
    "OptionError",
    "DatasetError",
    "BagError",
    "InferenceError",
]


class FisheyeInferError(Exception):
    """Base of every error raised by fisheye-infer on purpose."""


class CameraModelError(FisheyeInferError, ValueError):
    """A calibration file or camera parameter is malformed or out of range."""


class RigError(FisheyeInferError, ValueError):
    """A rig is incomplete or inconsistent: missing camera, NaN, non-rigid matrix, wrong size."""


class ConfigError(FisheyeInferError, ValueError):
    """A model configuration cannot be read, or uses a construct that is refused."""


class CheckpointError(FisheyeInferError):
    """A checkpoint does not fit the model: missing, unexpected or mis-shaped keys."""


class ExportError(FisheyeInferError):
    """An export cannot be carried out with the given inputs."""


class ParityError(ExportError):
    """The exported graph disagrees with the PyTorch model beyond the stated tolerance."""


class ArtifactError(FisheyeInferError):
    """An ONNX file lacks fisheye-infer metadata, or its metadata is invalid or unsupported."""


class FrameError(FisheyeInferError, ValueError):
    """An input frame is unusable: wrong camera names, size, dtype, or undecodable bytes."""


class OptionError(FisheyeInferError, ValueError):
    """A Detector or detect option is refused: a threshold outside [0, 1] or not a number, an unknown
    NMS kind, class names given as one string. Raised before any work, naming the option."""


class DatasetError(FisheyeInferError, ValueError):
    """A Fisheye3DOD folder is missing or malformed: the root, split, scene, camera or file is named."""


class BagError(FisheyeInferError, ValueError):
    """A recorded bag cannot be read: not a bag, damaged structure or compression, or no messages on the
    topics asked for. The bag and the problem are named."""


class InferenceError(FisheyeInferError):
    """ONNX Runtime failed while running a frame that passed validation."""
