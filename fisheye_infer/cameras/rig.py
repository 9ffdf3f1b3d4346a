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
    """One camera of a rig."""

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
    """Ordered named cameras; construct through the ``from_*``/``load`` class methods for clear errors."""

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
        """Validate a rig document; every problem is reported with its camera name and field."""
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
        """Assemble from per-camera models and cam2lidar matrices, in ``order`` (default: ``models`` order)."""
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
        """
        from fisheye_infer.cameras.calibration_files import place_cameras, read_calibrations

        groups = read_calibrations(files, format, names, trust_chain)
        cam2lidar = place_cameras(groups, read_lidar2cam_json(extrinsics), str(extrinsics))
        models = {c.name: c.model for _, cams in groups for c in cams}
        return cls.from_cameras(models, cam2lidar, name=name or Path(files[0]).stem)

    @classmethod
    def load(cls, path: str | Path) -> Rig:
        """Read a rig file (``.json``, ``.yaml`` or ``.yml``)."""
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
        """
        models, cam2lidar = pinhole_list_cameras(data, source)
        return cls.from_cameras(models, cam2lidar, name=name)

    def save(self, path: str | Path) -> Path:
        """Write the rig file; YAML for ``.yaml``/``.yml``, JSON otherwise."""
        return write_rig_document(self.model_dump(mode="json"), path)

    # -- access ---------------------------------------------------------------------------

    @property
    def names(self) -> list[str]:
        return [c.name for c in self.cameras]

    def __len__(self) -> int:
        return len(self.cameras)

    def camera(self, name: str) -> RigCamera:
        for cam in self.cameras:
            if cam.name == name:
                return cam
        raise RigError(f"camera '{name}': not in the rig (cameras: {', '.join(self.names)})")

    def subset(self, names: Sequence[str]) -> Rig:
        """The rig of ``names`` alone, in that order: a reduced layout (two of four fisheye cameras, say) that a
        model is trained for, rather than one it loses cameras from at run time."""
        if not names:
            raise RigError(f"cameras: expected at least one of {', '.join(self.names)}")
        repeated = sorted({n for n in names if list(names).count(n) > 1})
        if repeated:
            raise RigError(f"cameras: {', '.join(repeated)} named more than once")
        cameras = tuple(self.camera(name) for name in names)
        return self.model_copy(update={"cameras": cameras, "name": f"{self.name}[{'+'.join(names)}]"})

    def cam2lidar(self) -> np.ndarray:
        """(N, 4, 4) float64 in camera order."""
        return np.stack([c.matrix for c in self.cameras])

    def lidar2cam(self) -> np.ndarray:
        """(N, 4, 4) float64 inverses of ``cam2lidar``, computed in numpy."""
        return np.linalg.inv(self.cam2lidar())

    def shared_model(self) -> Any:
        """The one camera model all cameras share (Fisheye3DOD's rig has one); a rig whose cameras differ is refused,
        naming the camera."""
        first = self.cameras[0].model
        for cam in self.cameras[1:]:
            if cam.model != first:
                raise RigError(
                    f"camera '{cam.name}': its camera model differs from '{self.cameras[0].name}'; "
                    "expected one model shared by all cameras"
                )
        return first

    def require(self, names: Sequence[str], image_size: tuple[int, int] | None = None) -> None:
        """Check that the rig has exactly ``names`` in that order and, if given, images of ``image_size`` (W, H)."""
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
        image size, position and heading."""
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
    """The Fisheye3DOD rig shipped with the package: one 800x800 220-degree OCam model, four cameras."""
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
    folder holding ``calib_results.txt`` and ``lidar2cam.json``."""
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
