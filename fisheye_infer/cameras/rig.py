"""A rig: ordered, named cameras, each with a camera model and its pose in the lidar frame.

Frames: the lidar frame is x forward, y left, z up (metres); each camera frame is OpenCV's
(x right, y down, z forward). ``cam2lidar`` maps camera-frame points into the lidar frame.
The camera order is the model's input order (Fisheye3DOD: front, left, right, rear).

A rig is read from an OCam ``calib_results.txt`` plus ``lidar2cam.json``, from Fisheye3DOD
``sensor_metadata.txt`` files (CARLA poses, "compat" or "exact" convention), from the project's
own rig file (JSON or YAML) or from a pinhole camera list (``rig-pinhole6/cameras.json``), and
written to the rig file; ``rig_files`` parses those formats, `Rig` validates the result.
``Rig.hash`` is a stable content hash that ties an exported model to the rig its geometry tables
were computed for.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from fisheye_infer.cameras import rig_construction, rig_inspection
from fisheye_infer.cameras.carla_poses import Convention
from fisheye_infer.cameras.default_rigs import (
    FISHEYE3DOD_CAMERAS,
    PINHOLE_CAMERAS,
    default_rig,
    pinhole_rig,
    resolve_rig,
)
from fisheye_infer.cameras.kalibr_camchain import TrustChain
from fisheye_infer.cameras.rig_camera import RigCamera
from fisheye_infer.cameras.rig_files import RIG_SCHEMA_VERSION, write_rig_document
from fisheye_infer.errors import RigError

__all__ = [
    "Rig",
    "RigCamera",
    "FISHEYE3DOD_CAMERAS",
    "PINHOLE_CAMERAS",
    "RIG_SCHEMA_VERSION",
    "default_rig",
    "pinhole_rig",
    "resolve_rig",
]


class Rig(BaseModel):
    """Ordered named cameras; construct through the ``from_*``/``load`` class methods for clear errors.

    The camera order is the model's input order. A rig is a frozen pydantic object and saves to a rig file
    (JSON or YAML) that [`load`][fisheye_infer.cameras.rig.Rig.load] reads back.

    Attributes:
        schema_version (Literal[1]): The rig file's schema version.
        name (str): A label for messages and the ``describe`` table; not part of ``hash``.
        cameras (tuple[RigCamera, ...]): The cameras, at least one, with unique names.

    Raises:
        pydantic.ValidationError: Constructed directly, with no cameras or repeated names (the ``from_*``
            methods and ``load`` raise `RigError` instead, naming the camera and field).

    Examples:
        ```python
        from fisheye_infer.cameras.rig import Rig

        rig = Rig.load("rig.yaml")                                          # the project's rig file
        rig = Rig.from_ocam_extrinsics("calib_results.txt", "lidar2cam.json")
        rig = Rig.from_calibration(["camchain.yaml"], "lidar2cam.json")    # Kalibr, ROS, OpenCV, OCamCalib
        print(rig.names, rig.hash)
        print(rig.describe())
        rig.save("my_rig.json")
        ```
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    schema_version: Literal[1] = RIG_SCHEMA_VERSION
    name: str = "rig"
    cameras: tuple[RigCamera, ...] = Field(min_length=1)

    @model_validator(mode="after")
    def _unique_names(self) -> Rig:
        seen = [c.name for c in self.cameras]
        dupes = sorted({n for n in seen if seen.count(n) > 1})
        if dupes:
            raise ValueError(f"camera names must be unique; repeated: {', '.join(dupes)}")
        return self

    # -- construction ---------------------------------------------------------------------

    @classmethod
    def from_dict(cls, data: Any, source: str = "rig") -> Rig:
        """Validate a rig document; every problem is reported with its camera name and field.

        Args:
            data (Any): The document: ``{"name": ..., "cameras": [{"name", "model", "cam2lidar"}, ...]}``.
            source (str): What the error message calls the document (a file name).

        Returns:
            Rig: The rig.

        Raises:
            RigError: The document is not a valid rig.
        """
        return rig_construction.from_dict(cls, data, source)

    @classmethod
    def from_cameras(
        cls,
        models: dict[str, Any],
        cam2lidar: dict[str, np.ndarray],
        order: Sequence[str] | None = None,
        name: str = "rig",
    ) -> Rig:
        """Assemble from per-camera models and cam2lidar matrices, in ``order`` (default: ``models`` order).

        Args:
            models (dict[str, Any]): Camera name -> camera model (an object or its dict).
            cam2lidar (dict[str, np.ndarray]): Camera name -> 4x4 camera-to-lidar transform, metres.
            order (Sequence[str] | None): The cameras to take, in the rig's order; None takes every one of
                ``models`` in its order.
            name (str): The rig's name.

        Returns:
            Rig: The rig.

        Raises:
            RigError: A camera of ``order`` without a model or extrinsics, or an invalid model or transform.
        """
        return rig_construction.from_cameras(cls, models, cam2lidar, order, name)

    @classmethod
    def from_ocam_extrinsics(
        cls,
        calib: str | Path,
        lidar2cam_json: str | Path,
        order: Sequence[str] | None = None,
        fov: float = 220.0,
        name: str | None = None,
    ) -> Rig:
        """One OCam file shared by all cameras + ``{"cameras": {name: lidar2cam 4x4}}``.

        Without ``order``, Fisheye3DOD's order is used when the file has exactly its cameras.

        Args:
            calib (str | Path): An OCamCalib ``calib_results.txt``.
            lidar2cam_json (str | Path): JSON ``{"cameras": {name: 4x4 lidar2cam}}``, metres.
            order (Sequence[str] | None): The camera order; None: Fisheye3DOD's for its four cameras, else the
                file's.
            fov (float): The OCam model's full field of view, degrees.
            name (str | None): The rig's name; None: the extrinsics file's folder name.

        Returns:
            Rig: The rig, every camera with the same model.

        Raises:
            RigError: An unreadable or invalid file, a matrix that is not a finite invertible 4x4, or a camera
                of ``order`` missing from the extrinsics.
        """
        return rig_construction.from_ocam_extrinsics(cls, calib, lidar2cam_json, order, fov, name)

    @classmethod
    def from_sensor_metadata(
        cls,
        vehicle_dir: str | Path,
        calib: str | Path,
        cameras: Sequence[str] = FISHEYE3DOD_CAMERAS,
        frame_id: str | None = None,
        convention: Convention = "compat",
        fov: float = 220.0,
    ) -> Rig:
        """Rig of one Fisheye3DOD frame from ``<scene>/<vehicle>/<sensor>/sensor_metadata.txt``.

        ``frame_id`` defaults to the first frame that every camera and the lidar recorded.

        Args:
            vehicle_dir (str | Path): The ``<scene>/<vehicle>`` folder.
            calib (str | Path): The OCamCalib ``calib_results.txt`` all cameras share.
            cameras (Sequence[str]): The sensor folders, in the rig's order.
            frame_id (str | None): The frame whose poses to take; None: the first that all recorded.
            convention (Convention): ``"compat"`` (the official code's CARLA pose conversion) or ``"exact"``.
            fov (float): The OCam model's full field of view, degrees.

        Returns:
            Rig: The rig, named ``<scene>/<vehicle>@<frame>``.

        Raises:
            RigError: A missing or unreadable file, or a frame that the lidar or a camera did not record.
        """
        return rig_construction.from_sensor_metadata(cls, vehicle_dir, calib, cameras, frame_id, convention, fov)

    @classmethod
    def from_calibration(
        cls,
        files: Sequence[str | Path],
        extrinsics: str | Path,
        format: str | None = None,
        names: Sequence[str] | None = None,
        name: str | None = None,
        trust_chain: TrustChain | None = None,
    ) -> Rig:
        """Cameras from calibration files (``calibration_files``: Kalibr, ROS ``CameraInfo``, OpenCV, OCamCalib) placed
        in the lidar frame by ``{"cameras": {name: lidar2cam 4x4}}`` (``extrinsics``): each Kalibr camchain by one of
        its cameras there (any other there must agree with the chain: 1 mm, 0.06 degrees), every other camera by
        its own. ``names`` renames the cameras in file order; ``trust_chain`` (``"cn_cnm1"`` or ``"imu"``): which of
        a camchain's ``T_cn_cnm1`` and ``T_cam_imu`` places its cameras where the two disagree.

        Args:
            files (Sequence[str | Path]): Calibration files (see
                [`read_calibration`][fisheye_infer.cameras.calibration_files.read_calibration]).
            extrinsics (str | Path): JSON ``{"cameras": {name: 4x4 lidar2cam}}``, metres.
            format (str | None): The files' format (``"kalibr"``, ``"ros"``, ``"opencv"``, ``"ocam"``); None
                recognises each from its content.
            names (Sequence[str] | None): New camera names, one per camera in file order.
            name (str | None): The rig's name; None: the first file's stem.
            trust_chain (TrustChain | None): ``"cn_cnm1"`` or ``"imu"``; None refuses a camchain whose two
                sources disagree.

        Returns:
            Rig: The cameras in file order.

        Raises:
            RigError: An unreadable file, a camera model that cannot be represented, a camera without a pose,
                or a chain and extrinsics that disagree.

        Examples:
            ```python
            rig = Rig.from_calibration(["camchain.yaml"], "lidar2cam.json", names=["front", "left", "right", "rear"])
            ```
        """
        return rig_construction.from_calibration(cls, files, extrinsics, format, names, name, trust_chain)

    @classmethod
    def load(cls, path: str | Path) -> Rig:
        """Read a rig file (``.json``, ``.yaml`` or ``.yml``), or a pinhole camera list (``cameras.json``).

        Args:
            path (str | Path): The file.

        Returns:
            Rig: The rig.

        Raises:
            RigError: A missing or unreadable file, or one that is not a valid rig (named by camera and field).
        """
        return rig_construction.load(cls, path)

    @classmethod
    def from_pinhole_list(cls, data: dict[str, Any], source: str = "cameras", name: str = "rig") -> Rig:
        """Distortion-free cameras given as ``K`` (3x3 pixel intrinsics) and ``lidar2cam`` (4x4), in list order.

        ``cam2lidar`` is ``inv(lidar2cam)`` in float64. A camera with distortion, skew or a K whose
        last row is not (0, 0, 1) is refused by name: the pinhole detectors take ideal pinhole images.

        Args:
            data (dict[str, Any]): The document: a list of cameras with ``name``, ``width``, ``height``, ``K``
                and ``lidar2cam``.
            source (str): What error messages call the document.
            name (str): The rig's name.

        Returns:
            Rig: The rig of [`Pinhole`][fisheye_infer.cameras.pinhole_models.Pinhole] cameras.

        Raises:
            RigError: A missing field, a matrix of the wrong shape, distortion or skew.
        """
        return rig_construction.from_pinhole_list(cls, data, source, name)

    def save(self, path: str | Path) -> Path:
        """Write the rig file; YAML for ``.yaml``/``.yml``, JSON otherwise.

        Args:
            path (str | Path): Where to write it; an existing file is replaced.

        Returns:
            Path: ``path``.
        """
        return write_rig_document(self.model_dump(mode="json"), path)

    # -- access ---------------------------------------------------------------------------

    @property
    def names(self) -> list[str]:
        """The camera names, in order."""
        return [c.name for c in self.cameras]

    def __len__(self) -> int:
        return len(self.cameras)

    def camera(self, name: str) -> RigCamera:
        """The camera called ``name``.

        Args:
            name (str): A camera name.

        Returns:
            RigCamera: The camera.

        Raises:
            RigError: No camera of that name.
        """
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise RigError(f"camera '{name}': not in the rig (cameras: {', '.join(self.names)})")

    def subset(self, names: Sequence[str]) -> Rig:
        """The rig of ``names`` alone, in that order: a reduced layout (two of four fisheye cameras, say) that a
        model is trained for, rather than one it loses cameras from at run time.

        Args:
            names (Sequence[str]): Camera names, each once.

        Returns:
            Rig: The reduced rig, named ``<name>[a+b]``.

        Raises:
            RigError: No names, a name repeated or not in the rig.
        """
        return rig_inspection.subset(self, names)

    def cam2lidar(self) -> np.ndarray:
        """The cameras' poses.

        Returns:
            np.ndarray: (N, 4, 4) float64 camera-to-lidar transforms, in camera order.
        """
        return np.stack([c.matrix for c in self.cameras])

    def lidar2cam(self) -> np.ndarray:
        """The inverses of the cameras' poses, computed in numpy.

        Returns:
            np.ndarray: (N, 4, 4) float64 lidar-to-camera transforms, in camera order.
        """
        return np.linalg.inv(self.cam2lidar())

    def shared_model(self) -> Any:
        """The one camera model all cameras share (Fisheye3DOD's rig has one); a rig whose cameras differ is refused,
        naming the camera.

        Returns:
            Any: The camera model.

        Raises:
            RigError: A camera whose model differs from the first camera's.
        """
        return rig_inspection.shared_model(self)

    def require(self, names: Sequence[str], image_size: tuple[int, int] | None = None) -> None:
        """Check that the rig has exactly ``names`` in that order and, if given, images of ``image_size`` (W, H).

        Args:
            names (Sequence[str]): The camera names expected, in order.
            image_size (tuple[int, int] | None): (width, height) in pixels every camera must have; None: any.

        Raises:
            RigError: A camera missing, another order, or another image size (named by camera).
        """
        rig_inspection.require(self, names, image_size)

    @property
    def hash(self) -> str:
        """sha256 (hex, first 16 digits) of the cameras' canonical JSON; the rig's name does not count.

        Numbers are rounded to 10 decimals and -0.0 is written as 0.0 first, so the hash does not
        depend on the last bits of a matrix inverse (``from_ocam_extrinsics`` inverts lidar2cam with
        LAPACK, whose rounding may differ between machines; entries that are zero up to 1e-17 noise
        would otherwise change it).
        """
        return rig_inspection.content_hash(self)

    def describe(self) -> str:
        """A human-readable table: camera, model, which calibration (cameras with the same number share one),
        image size, position and heading.

        Returns:
            str: The table, one line per camera after a header.
        """
        return rig_inspection.describe(self)
