"""A rig: ordered, named cameras, each with a camera model and its pose in the lidar frame.

Frames: the lidar frame is x forward, y left, z up (metres); each camera frame is OpenCV's
(x right, y down, z forward). ``cam2lidar`` maps camera-frame points into the lidar frame.
The camera order is the model's input order (Fisheye3DOD: front, left, right, rear).

A rig is read from
- an OCam ``calib_results.txt`` shared by all cameras plus a ``lidar2cam.json``,
- Fisheye3DOD ``sensor_metadata.txt`` files (CARLA poses, "compat" or "exact" convention),
- the project's own rig file (JSON or YAML, with ``schema_version``),
- a pinhole camera list (``{"cameras": [{"name", "width", "height", "K", "distortion": "none",
  "lidar2cam"}, ...]}``, the layout of ``rig-pinhole6/cameras.json``),
and written to the rig file. ``Rig.hash`` is a stable content hash that ties an exported model
to the rig its geometry tables were computed for.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Sequence
from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import Any, Final, Literal

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from fisheye_infer.cameras.camera_models import AnyCameraModel, OCamModel
from fisheye_infer.cameras.carla_poses import Convention, cam2lidar_from_poses, read_sensor_metadata
from fisheye_infer.errors import CameraModelError, RigError

__all__ = [
    "Rig",
    "RigCamera",
    "FISHEYE3DOD_CAMERAS",
    "PINHOLE_CAMERAS",
    "RIG_SCHEMA_VERSION",
    "default_rig",
    "resolve_rig",
]

RIG_SCHEMA_VERSION: Final = 1
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
            raise RigError(f"{source}: " + _describe(exc, data)) from None

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
        model = _read_ocam(calib, fov)
        path = Path(lidar2cam_json)
        try:
            doc = json.loads(path.read_text())
        except (OSError, json.JSONDecodeError) as exc:
            raise RigError(f"extrinsics {path}: cannot be read as JSON ({exc})") from exc
        cams = doc.get("cameras") if isinstance(doc, dict) else None
        if not isinstance(cams, dict) or not cams:
            raise RigError(f'extrinsics {path}: expected {{"cameras": {{name: 4x4 lidar2cam}}}}')
        if order is None:
            order = FISHEYE3DOD_CAMERAS if set(cams) == set(FISHEYE3DOD_CAMERAS) else list(cams)
        cam2lidar = {}
        for cam, m in cams.items():
            arr = np.asarray(m, dtype=np.float64)
            if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
                raise RigError(
                    f"camera '{cam}' (lidar2cam in {path}): expected a finite 4x4 matrix, got shape {arr.shape}"
                )
            cam2lidar[cam] = np.linalg.inv(arr)
        return cls.from_cameras({c: model for c in cams}, cam2lidar, order, name=name or path.parent.name)

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
        model = _read_ocam(calib, fov)
        lidar = read_sensor_metadata(root / "lidar" / "sensor_metadata.txt")
        poses = {cam: read_sensor_metadata(root / cam / "sensor_metadata.txt") for cam in cameras}
        if frame_id is None:
            common = set(lidar).intersection(*(set(p) for p in poses.values()))
            if not common:
                raise RigError(f"{root}: no frame is recorded by the lidar and every camera ({', '.join(cameras)})")
            frame_id = min(common)
        frame_id = f"{int(frame_id):08d}"
        if frame_id not in lidar:
            raise RigError(f"{root}: frame {frame_id} missing from lidar/sensor_metadata.txt")
        cam2lidar = {}
        for cam, p in poses.items():
            if frame_id not in p:
                raise RigError(f"camera '{cam}': frame {frame_id} missing from its sensor_metadata.txt")
            cam2lidar[cam] = cam2lidar_from_poses(p[frame_id], lidar[frame_id], convention)
        return cls.from_cameras(
            {c: model for c in cameras}, cam2lidar, cameras, name=f"{root.parent.name}/{root.name}@{frame_id}"
        )

    @classmethod
    def load(cls, path: str | Path) -> Rig:
        """Read a rig file (``.json``, ``.yaml`` or ``.yml``)."""
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise RigError(f"rig file {path}: cannot be read ({exc.strerror})") from exc
        try:
            data = yaml.safe_load(text) if path.suffix.lower() in (".yaml", ".yml") else json.loads(text)
        except (yaml.YAMLError, json.JSONDecodeError) as exc:
            raise RigError(
                f"rig file {path}: not valid {'YAML' if path.suffix.lower() in ('.yaml', '.yml') else 'JSON'}: {exc}"
            ) from exc
        if isinstance(data, dict) and data.get("schema_version", RIG_SCHEMA_VERSION) != RIG_SCHEMA_VERSION:
            raise RigError(
                f"rig file {path}: schema_version {data.get('schema_version')!r} is not supported "
                f"(expected {RIG_SCHEMA_VERSION})"
            )
        if _is_pinhole_list(data):
            return cls.from_pinhole_list(data, source=f"rig file {path}", name=path.parent.name or path.stem)
        return cls.from_dict(data, source=f"rig file {path}")

    @classmethod
    def from_pinhole_list(cls, data: dict[str, Any], source: str = "cameras", name: str = "rig") -> Rig:
        """Distortion-free cameras given as ``K`` (3x3 pixel intrinsics) and ``lidar2cam`` (4x4), in list order.

        ``cam2lidar`` is ``inv(lidar2cam)`` in float64. A camera with distortion, skew or a K whose
        last row is not (0, 0, 1) is refused by name: the pinhole detectors take ideal pinhole images.
        """
        models: dict[str, Any] = {}
        cam2lidar: dict[str, np.ndarray] = {}
        for i, cam in enumerate(data["cameras"]):
            label = f"{source}: camera '{cam.get('name', f'#{i}')}'"
            k = np.asarray(cam.get("K"), dtype=np.float64)
            lidar2cam = np.asarray(cam.get("lidar2cam"), dtype=np.float64)
            if k.shape != (3, 3) or not np.all(np.isfinite(k)):
                raise RigError(f"{label} (K): expected a finite 3x3 matrix, got shape {k.shape}")
            if k[0, 1] != 0 or k[1, 0] != 0 or not np.array_equal(k[2], (0.0, 0.0, 1.0)):
                raise RigError(f"{label} (K): expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {k.tolist()}")
            if cam.get("distortion", "none") not in ("none", None):
                raise RigError(
                    f"{label} (distortion): {cam.get('distortion')!r} is not supported; "
                    "expected 'none' (an ideal pinhole)"
                )
            if lidar2cam.shape != (4, 4) or not np.all(np.isfinite(lidar2cam)):
                raise RigError(f"{label} (lidar2cam): expected a finite 4x4 matrix, got shape {lidar2cam.shape}")
            if "name" not in cam or "width" not in cam or "height" not in cam:
                raise RigError(f"{label}: expected the fields name, width, height, K, lidar2cam")
            models[cam["name"]] = {
                "type": "pinhole",
                "width": cam["width"],
                "height": cam["height"],
                "fx": k[0, 0],
                "fy": k[1, 1],
                "cx": k[0, 2],
                "cy": k[1, 2],
            }
            cam2lidar[cam["name"]] = np.linalg.inv(lidar2cam)
        return cls.from_cameras(models, cam2lidar, name=name)

    def save(self, path: str | Path) -> Path:
        """Write the rig file; YAML for ``.yaml``/``.yml``, JSON otherwise."""
        path = Path(path)
        data = self.model_dump(mode="json")
        if path.suffix.lower() in (".yaml", ".yml"):
            path.write_text(yaml.safe_dump(data, sort_keys=False))
        else:
            path.write_text(json.dumps(data, indent=2) + "\n")
        return path

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

    def cam2lidar(self) -> np.ndarray:
        """(N, 4, 4) float64 in camera order."""
        return np.stack([c.matrix for c in self.cameras])

    def lidar2cam(self) -> np.ndarray:
        """(N, 4, 4) float64 inverses of ``cam2lidar``, computed in numpy."""
        return np.linalg.inv(self.cam2lidar())

    def shared_model(self) -> Any:
        """The one camera model all cameras share; the detectors were trained with a single intrinsic model."""
        first = self.cameras[0].model
        for cam in self.cameras[1:]:
            if cam.model != first:
                raise RigError(
                    f"camera '{cam.name}': its camera model differs from '{self.cameras[0].name}'; "
                    "this model needs one shared intrinsic calibration"
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
        """A human-readable table: camera, model, image size, position and heading."""
        width = max(24, *(len(n) for n in self.names))
        lines = [f"rig {self.name!r}  hash {self.hash}  frame: lidar (x forward, y left, z up)"]
        lines.append(
            f"  {'camera':<{width}} {'model':<15} {'image':>9} {'fov':>6}   {'position x, y, z (m)':<26} {'heading':>8}"
        )
        for cam in self.cameras:
            x, y, z = np.round(cam.position, 3) + 0.0  # no "-0.000"
            fov = getattr(cam.model, "fov", None)
            lines.append(
                f"  {cam.name:<{width}} {cam.model.type:<15} {cam.model.width:>4}x{cam.model.height:<4} "
                f"{fov if fov is not None else '-':>6}"
                f"   {x:>7.3f}, {y:>7.3f}, {z:>7.3f}     {round(math.degrees(cam.heading), 1) + 0.0:>7.1f}°"
            )
        return "\n".join(lines)


def _is_pinhole_list(data: Any) -> bool:
    """A camera list with ``K`` and ``lidar2cam`` per camera (not the project's rig schema)."""
    cams = data.get("cameras") if isinstance(data, dict) else None
    return (
        isinstance(cams, list)
        and bool(cams)
        and all(isinstance(c, dict) and "K" in c and "lidar2cam" in c for c in cams)
    )


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


def _read_ocam(calib: str | Path, fov: float) -> OCamModel:
    try:
        return OCamModel.from_file(calib, fov=fov)
    except CameraModelError as exc:
        raise RigError(str(exc)) from exc


def _describe(exc: ValidationError, data: Any) -> str:
    """Turn pydantic's locations into 'camera <name>: field: message'."""
    cameras = data.get("cameras") if isinstance(data, dict) else None
    parts = []
    for err in exc.errors():
        loc = list(err["loc"])
        where = ".".join(str(x) for x in loc) or "rig"
        if len(loc) >= 2 and loc[0] == "cameras" and isinstance(loc[1], int):
            entry = cameras[loc[1]] if isinstance(cameras, (list, tuple)) and loc[1] < len(cameras) else None
            name = entry.get("name") if isinstance(entry, dict) else None
            field = (
                ".".join(str(x) for x in loc[2:] if x not in ("ocam", "kannala_brandt", "equidistant", "pinhole"))
                or "entry"
            )
            where = f"camera '{name}' ({field})" if name else f"camera #{loc[1]} ({field})"
        msg = err["msg"].removeprefix("Value error, ")
        parts.append(f"{where}: {msg}")
    return "; ".join(parts)


@lru_cache(maxsize=1)
def default_rig() -> Rig:
    """The Fisheye3DOD rig shipped with the package: one 800x800 220-degree OCam model, four cameras."""
    base = resources.files("fisheye_infer") / "data" / "rig-fisheye3dod"
    with resources.as_file(base) as folder:
        return Rig.from_ocam_extrinsics(folder / "calib_results.txt", folder / "lidar2cam.json", name="fisheye3dod")


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
