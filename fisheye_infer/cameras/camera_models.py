"""Camera models behind one interface: ray <-> pixel, with validity, and the union a rig file holds.

Every model works in the OpenCV camera frame (x right, y down, z forward) and in pixel
coordinates whose integer values are pixel centres (the ``cv2.remap`` convention):

    uv, valid = camera.project(points)    # (N, 3) -> (N, 2) float64, (N,) bool
    rays = camera.unproject(uv)           # (N, 2) -> (N, 3) unit vectors

``OCamModel`` (``ocam_model``) is the Scaramuzza/OCamCalib model the Fisheye3DOD checkpoints were trained
with. ``KannalaBrandt`` (``kannala_brandt``) is OpenCV's fisheye model (and the paper's 5-term r(theta));
``Equidistant`` and ``Pinhole`` (``pinhole_models``) complete the set of the paper's models. The wide-angle
models that robot calibration tools write are ``DoubleSphere``, ``ExtendedUnified`` and ``Omnidirectional``
(``unified_models``), and OpenCV's ``DistortedPinhole`` (``pinhole_models``). What they share is
``camera_model_base``'s.

The models are frozen pydantic objects so that a rig file can carry them as plain JSON; ``AnyCameraModel``
tells them apart by their ``type``.
"""

from __future__ import annotations

from typing import Annotated

from pydantic import Field

from fisheye_infer.cameras.camera_model_base import CameraModel, incidence_angle
from fisheye_infer.cameras.kannala_brandt import Equidistant, KannalaBrandt
from fisheye_infer.cameras.ocam_model import OCamModel
from fisheye_infer.cameras.pinhole_models import DistortedPinhole, Pinhole
from fisheye_infer.cameras.unified_models import DoubleSphere, ExtendedUnified, Omnidirectional

__all__ = [
    "CameraModel",
    "OCamModel",
    "KannalaBrandt",
    "Equidistant",
    "Pinhole",
    "DistortedPinhole",
    "DoubleSphere",
    "ExtendedUnified",
    "Omnidirectional",
    "AnyCameraModel",
    "incidence_angle",
]

AnyCameraModel = Annotated[
    OCamModel
    | KannalaBrandt
    | Equidistant
    | Pinhole
    | DistortedPinhole
    | DoubleSphere
    | ExtendedUnified
    | Omnidirectional,
    Field(discriminator="type"),
]
