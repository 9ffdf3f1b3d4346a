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

import hashlib
import json
import math
from collections.abc import Sequence
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from fisheye_infer.cameras.camera_models import AnyCameraModel
from fisheye_infer.cameras.carla_poses import Convention
from fisheye_infer.cameras.field_of_view import reported_fov
from fisheye_infer.cameras.kalibr_camchain import TrustChain
from fisheye_infer.cameras.rig_files import (
    RIG_SCHEMA_VERSION,
    describe_validation_error,
    is_pinhole_list,
    pinhole_list_cameras,
    read_lidar2cam_json,
    read_ocam,
    read_rig_document,
    read_sensor_metadata_poses,
    write_rig_document,
)
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

#: The detectors' input order for Fisheye3DOD.
FISHEYE3DOD_CAMERAS = ("fisheye_camera_front", "fisheye_camera_left", "fisheye_camera_right", "fisheye_camera_rear")
#: The six nuScenes-like pinhole cameras in the pinhole baselines' input order (rear_right before rear_left).
PINHOLE_CAMERAS = (
    "nu_rgb_camera_front",
    "nu_rgb_camera_front_left",
    "nu_rgb_camera_front_right",
    "nu_rgb_camera_rear",
    "nu_rgb_camera_rear_right",
    "nu_rgb_camera_rear_left",
)
_RIGID_TOLERANCE = 1e-4


class RigCamera(BaseModel):
    """One camera of a rig: its name, lens and pose.

    Attributes:
        name (str): The camera's name (non-empty, unique in its rig).
        model (AnyCameraModel): Its camera model, one of the models above, told apart by ``type``.
        cam2lidar (tuple[tuple[float, float, float, float], ...]): 4x4 rigid transform from the camera
            (OpenCV) frame to the lidar frame, metres; the last row is (0, 0, 0, 1).

    Raises:
        pydantic.ValidationError: ``cam2lidar`` not 4x4, not finite or not rigid (within 1e-4), or an invalid
            model.

    Examples:
        ```python
        from fisheye_infer.cameras.rig import default_rig

        front = default_rig().camera("fisheye_camera_front")
        front.model.type, front.position, front.heading   # "ocam", (3,) metres, radians (0 = forward)
        ```
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(min_length=1)
    model: AnyCameraModel
    cam2lidar: tuple[tuple[float, float, float, float], ...] = Field(description="4x4, camera (OpenCV) to lidar frame")

    @field_validator("cam2lidar")
    @classmethod
    def _rigid(cls, value: tuple[tuple[float, ...], ...]) -> tuple[tuple[float, ...], ...]:
        m = np.asarray(value, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"must be 4x4, got {len(value)} rows")
        if not np.all(np.isfinite(m)):
            raise ValueError("contains NaN or infinity")
        if not np.allclose(m[3], (0, 0, 0, 1), atol=1e-9):
            raise ValueError(f"last row must be [0, 0, 0, 1], got {m[3].tolist()}")
        rot = m[:3, :3]
        err = np.abs(rot.T @ rot - np.eye(3)).max()
        if err > _RIGID_TOLERANCE or np.linalg.det(rot) < 0:
            raise ValueError(f"rotation is not rigid (|R^T R - I| = {err:.2e}, det = {np.linalg.det(rot):.4f})")
        return value

    @property
    def matrix(self) -> np.ndarray:
        """cam2lidar as a (4, 4) float64 array."""
        return np.asarray(self.cam2lidar, dtype=np.float64)

    @property
    def position(self) -> np.ndarray:
        """Camera centre in the lidar frame (m)."""
        return self.matrix[:3, 3]

    @property
    def heading(self) -> float:
        """Azimuth of the optical axis in the lidar x-y plane, radians (0 = forward, +pi/2 = left)."""
        axis = self.matrix[:3, 2]
        return math.atan2(axis[1], axis[0])


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
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            raise RigError(f"{source}: " + describe_validation_error(exc, data)) from None

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
        order = list(order or models)
        for cam in order:
            if cam not in models:
                raise RigError(f"camera '{cam}': no camera model given (have: {', '.join(models)})")
            if cam not in cam2lidar:
                raise RigError(f"camera '{cam}': no extrinsics given (have: {', '.join(cam2lidar)})")
        cameras = [
            {
                "name": cam,
                "model": _as_dict(models[cam]),
                "cam2lidar": np.asarray(cam2lidar[cam], dtype=np.float64).tolist(),
            }
            for cam in order
        ]
        return cls.from_dict({"name": name, "cameras": cameras})

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
        model = read_ocam(calib, fov)
        cam2lidar = read_lidar2cam_json(lidar2cam_json)
        if order is None:
            order = FISHEYE3DOD_CAMERAS if set(cam2lidar) == set(FISHEYE3DOD_CAMERAS) else list(cam2lidar)
        name = name or Path(lidar2cam_json).parent.name
        return cls.from_cameras({c: model for c in cam2lidar}, cam2lidar, order, name=name)

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
        root = Path(vehicle_dir)
        model = read_ocam(calib, fov)
        frame_id, cam2lidar = read_sensor_metadata_poses(root, cameras, frame_id, convention)
        return cls.from_cameras(
            {c: model for c in cameras}, cam2lidar, cameras, name=f"{root.parent.name}/{root.name}@{frame_id}"
        )

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
        from fisheye_infer.cameras.calibration_files import place_cameras, read_calibrations

        groups = read_calibrations(files, format, names, trust_chain)
        cam2lidar = place_cameras(groups, read_lidar2cam_json(extrinsics), str(extrinsics))
        models = {c.name: c.model for _, cams in groups for c in cams}
        return cls.from_cameras(models, cam2lidar, name=name or Path(files[0]).stem)

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
        path = Path(path)
        data = read_rig_document(path)
        if is_pinhole_list(data):
            return cls.from_pinhole_list(data, source=f"rig file {path}", name=path.parent.name or path.stem)
        return cls.from_dict(data, source=f"rig file {path}")

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
        models, cam2lidar = pinhole_list_cameras(data, source)
        return cls.from_cameras(models, cam2lidar, name=name)

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
        if not names:
            raise RigError(f"cameras: expected at least one of {', '.join(self.names)}")
        repeated = sorted({n for n in names if list(names).count(n) > 1})
        if repeated:
            raise RigError(f"cameras: {', '.join(repeated)} named more than once")
        cameras = tuple(self.camera(name) for name in names)
        return self.model_copy(update={"cameras": cameras, "name": f"{self.name}[{'+'.join(names)}]"})

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
        first = self.cameras[0].model
        for cam in self.cameras[1:]:
            if cam.model != first:
                raise RigError(
                    f"camera '{cam.name}': its camera model differs from '{self.cameras[0].name}'; "
                    "expected one model shared by all cameras"
                )
        return first

    def require(self, names: Sequence[str], image_size: tuple[int, int] | None = None) -> None:
        """Check that the rig has exactly ``names`` in that order and, if given, images of ``image_size`` (W, H).

        Args:
            names (Sequence[str]): The camera names expected, in order.
            image_size (tuple[int, int] | None): (width, height) in pixels every camera must have; None: any.

        Raises:
            RigError: A camera missing, another order, or another image size (named by camera).
        """
        for name in names:
            if name not in self.names:
                raise RigError(f"camera '{name}': missing from the rig (rig has: {', '.join(self.names)})")
        if list(names) != self.names:
            raise RigError(f"camera order: expected {', '.join(names)}; the rig has {', '.join(self.names)}")
        if image_size is not None:
            for cam in self.cameras:
                size = (cam.model.width, cam.model.height)
                if size != tuple(image_size):
                    raise RigError(
                        f"camera '{cam.name}': image is {size[0]}x{size[1]}, "
                        f"model expects {image_size[0]}x{image_size[1]}"
                    )

    @property
    def hash(self) -> str:
        """sha256 (hex, first 16 digits) of the cameras' canonical JSON; the rig's name does not count.

        Numbers are rounded to 10 decimals and -0.0 is written as 0.0 first, so the hash does not
        depend on the last bits of a matrix inverse (``from_ocam_extrinsics`` inverts lidar2cam with
        LAPACK, whose rounding may differ between machines; entries that are zero up to 1e-17 noise
        would otherwise change it).
        """
        doc = json.dumps(
            _canonical([c.model_dump(mode="json") for c in self.cameras]), sort_keys=True, separators=(",", ":")
        )
        return hashlib.sha256(doc.encode()).hexdigest()[:16]

    def describe(self) -> str:
        """A human-readable table: camera, model, which calibration (cameras with the same number share one),
        image size, position and heading.

        Returns:
            str: The table, one line per camera after a header.
        """
        width = max(24, *(len(n) for n in self.names))
        calibrations = list(dict.fromkeys(cam.model for cam in self.cameras))
        lines = [f"rig {self.name!r}  hash {self.hash}  frame: lidar (x forward, y left, z up)"]
        lines.append(
            f"  {'camera':<{width}} {'model':<17} {'lens':>4} {'image':>9} {'fov':>7}   {'position x, y, z (m)':<26} "
            f"{'heading':>8}"
        )
        for cam in self.cameras:
            x, y, z = np.round(cam.position, 3) + 0.0  # no "-0.000"
            fov = reported_fov(cam.model)
            lines.append(
                f"  {cam.name:<{width}} {cam.model.type:<17} {calibrations.index(cam.model) + 1:>4} "
                f"{cam.model.width:>4}x{cam.model.height:<4} {fov if fov is not None else '-':>7}"
                f"   {x:>7.3f}, {y:>7.3f}, {z:>7.3f}     {round(math.degrees(cam.heading), 1) + 0.0:>7.1f}°"
            )
        return "\n".join(lines)


def _canonical(value: Any) -> Any:
    """JSON data with every float rounded to 10 decimals and signed zeros made positive."""
    if isinstance(value, float):
        return round(value, 10) + 0.0
    if isinstance(value, dict):
        return {k: _canonical(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_canonical(v) for v in value]
    return value


def _as_dict(model: Any) -> Any:
    return model.model_dump() if isinstance(model, BaseModel) else model


@lru_cache(maxsize=1)
def default_rig() -> Rig:
    """The Fisheye3DOD rig shipped with the package: one 800x800 220-degree OCam model, four cameras.

    Returns:
        Rig: The rig ``fisheye3dod`` (front, left, right, rear), cached: every call returns the same object.

    Examples:
        ```python
        from fisheye_infer.cameras.rig import default_rig

        rig = default_rig()
        rig.names     # ["fisheye_camera_front", "fisheye_camera_left", "fisheye_camera_right", "fisheye_camera_rear"]
        ```
    """
    base = resources.files("fisheye_infer") / "data" / "rig-fisheye3dod"
    with resources.as_file(base) as folder:
        return Rig.from_ocam_extrinsics(folder / "calib_results.txt", folder / "lidar2cam.json", name="fisheye3dod")


def pinhole_rig() -> Rig:
    """The six-camera pinhole rig shipped with the package (``rig-pinhole6``): the pinhole baselines' 1280x720
    ideal 90-degree cameras in their input order, with constructed nuScenes-like extrinsics."""
    path = resources.files("fisheye_infer") / "data" / "rig-pinhole6" / "cameras.json"
    with resources.as_file(path) as file:
        return Rig.load(file)


def resolve_rig(spec: str | Path | None) -> Rig:
    """A rig from what a user types: nothing or ``default`` (the shipped rig), a rig file, or a
    folder holding ``calib_results.txt`` and ``lidar2cam.json``.

    Args:
        spec (str | Path | None): None or ``"default"``, a rig file (``.json``, ``.yaml``, ``.yml``) or a folder.

    Returns:
        Rig: The rig.

    Raises:
        RigError: No such file or folder, a folder without both files, or an invalid rig.
    """
    if spec is None or str(spec) == "default":
        return default_rig()
    path = Path(spec)
    if path.is_dir():
        calib, extrinsics = path / "calib_results.txt", path / "lidar2cam.json"
        if not (calib.is_file() and extrinsics.is_file()):
            raise RigError(f"rig folder {path}: expected calib_results.txt and lidar2cam.json in it")
        return Rig.from_ocam_extrinsics(calib, extrinsics)
    if not path.exists():
        raise RigError(f"rig {path}: no such file or folder (give a rig .json/.yaml, a folder, or 'default')")
    return Rig.load(path)
