"""The files a rig is read from and written to, taken apart into camera models and cam2lidar matrices.

Each format has its own parsing and its own error messages, which would otherwise crowd
[`Rig`][fisheye_infer.cameras.rig.Rig]: its ``from_*``/``load``/``save`` methods call in here and
then validate what comes back. Nothing here builds a ``Rig``, so this module does not import
``rig`` (no import cycle). The formats:

- an OCam ``calib_results.txt`` shared by all cameras plus a ``lidar2cam.json``
  (``{"cameras": {name: 4x4 lidar2cam}}``, the Fisheye3DOD rig folder),
- Fisheye3DOD ``<vehicle>/<sensor>/sensor_metadata.txt`` files (CARLA poses per frame),
- the project's own rig file (JSON or YAML, with ``schema_version``),
- a pinhole camera list (``{"cameras": [{"name", "width", "height", "K", "distortion": "none",
  "lidar2cam"}, ...]}``, the layout of ``rig-pinhole6/cameras.json``).

Readers report problems with the file, camera and field they concern, as `RigError`. Files are
read through ``text_input`` (a binary file is "not a rig file", YAML aliases are refused), and a value that
is not finite (YAML's ``.nan``, JSON's ``NaN``) is named as such.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any, Final

import numpy as np
import yaml
from pydantic import ValidationError

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.carla_poses import Convention, cam2lidar_from_poses, read_sensor_metadata
from fisheye_infer.cameras.text_input import load_yaml, read_text, short
from fisheye_infer.errors import CameraModelError, RigError

__all__ = [
    "RIG_SCHEMA_VERSION",
    "read_ocam",
    "read_lidar2cam_json",
    "read_sensor_metadata_poses",
    "read_rig_document",
    "is_pinhole_list",
    "pinhole_list_cameras",
    "write_rig_document",
    "describe_validation_error",
    "error_message",
]

RIG_SCHEMA_VERSION: Final = 1


def read_ocam(calib: str | Path, fov: float) -> OCamModel:
    """The OCam model in ``calib`` (``calib_results.txt``); its problems as `RigError`."""
    try:
        return OCamModel.from_file(calib, fov=fov)
    except CameraModelError as exc:
        raise RigError(str(exc)) from exc


def read_lidar2cam_json(path: str | Path) -> dict[str, np.ndarray]:
    """cam2lidar (4x4 float64) per camera, in file order, from ``{"cameras": {name: 4x4 lidar2cam}}``."""
    path = Path(path)
    doc = _json(path, read_text(path, "an extrinsics file"), "extrinsics")
    cams = doc.get("cameras") if isinstance(doc, dict) else None
    if not isinstance(cams, dict) or not cams:
        raise RigError(f'extrinsics {path}: expected {{"cameras": {{name: 4x4 lidar2cam}}}}')
    cam2lidar = {}
    for cam, m in cams.items():
        try:
            arr = np.asarray(m, dtype=np.float64)
        except (TypeError, ValueError):
            arr = np.full((0,), np.nan)
        label = f"camera {short(cam)} (lidar2cam in {path})"
        if arr.shape != (4, 4) or not np.all(np.isfinite(arr)):
            raise RigError(f"{label}: expected a finite 4x4 matrix, got {short(m)}")
        if abs(np.linalg.det(arr)) < 1e-9:
            raise RigError(f"{label}: not invertible (a rigid transform is)")
        cam2lidar[cam] = np.linalg.inv(arr)
    return cam2lidar


def _json(path: Path, text: str, what: str) -> Any:
    """The JSON document in ``text`` (``what`` names the file in the refusal)."""
    try:
        return json.loads(text)
    except json.JSONDecodeError as exc:
        raise RigError(f"{what} {path}: cannot be read as JSON ({exc})") from None
    except RecursionError:
        raise RigError(f"{what} {path}: cannot be read as JSON (nested too deeply)") from None


def read_sensor_metadata_poses(
    vehicle_dir: str | Path, cameras: Sequence[str], frame_id: str | None, convention: Convention
) -> tuple[str, dict[str, np.ndarray]]:
    """The frame id (8 digits) and cam2lidar per camera of one frame of ``<vehicle>/<sensor>/sensor_metadata.txt``.

    ``frame_id`` defaults to the first frame that every camera and the lidar recorded.
    """
    root = Path(vehicle_dir)
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
    return frame_id, cam2lidar


def _is_yaml(path: Path) -> bool:
    return path.suffix.lower() in (".yaml", ".yml")


def read_rig_document(path: Path) -> Any:
    """The parsed contents of a rig file (YAML for ``.yaml``/``.yml``, JSON otherwise), its
    ``schema_version`` checked when it has one; not yet validated as a rig."""
    text = read_text(path, "a rig file")
    data = load_yaml(text, f"rig file {path}") if _is_yaml(path) else _json(path, text, "rig file")
    if isinstance(data, dict) and data.get("schema_version", RIG_SCHEMA_VERSION) != RIG_SCHEMA_VERSION:
        raise RigError(
            f"rig file {path}: schema_version {data.get('schema_version')!r} is not supported "
            f"(expected {RIG_SCHEMA_VERSION})"
        )
    return data


def is_pinhole_list(data: Any) -> bool:
    """A camera list with ``K`` and ``lidar2cam`` per camera (not the project's rig schema)."""
    cams = data.get("cameras") if isinstance(data, dict) else None
    return (
        isinstance(cams, list)
        and bool(cams)
        and all(isinstance(c, dict) and "K" in c and "lidar2cam" in c for c in cams)
    )


def pinhole_list_cameras(data: dict[str, Any], source: str) -> tuple[dict[str, dict[str, Any]], dict[str, np.ndarray]]:
    """Pinhole models and cam2lidar (``inv(lidar2cam)``, float64) by camera name, in list order.

    A camera with distortion, skew or a K whose last row is not (0, 0, 1) is refused by name: the
    pinhole detectors take ideal pinhole images.
    """
    models: dict[str, dict[str, Any]] = {}
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
                f"{label} (distortion): {cam.get('distortion')!r} is not supported; expected 'none' (an ideal pinhole)"
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
    return models, cam2lidar


def write_rig_document(data: dict[str, Any], path: str | Path) -> Path:
    """Write a rig document; YAML for ``.yaml``/``.yml``, JSON otherwise."""
    path = Path(path)
    if _is_yaml(path):
        path.write_text(yaml.safe_dump(data, sort_keys=False))
    else:
        path.write_text(json.dumps(data, indent=2) + "\n")
    return path


#: The camera model types, which pydantic puts in an error's location (a discriminated union's tag).
_MODEL_TYPES = (
    "ocam",
    "kannala_brandt",
    "equidistant",
    "pinhole",
    "distorted_pinhole",
    "double_sphere",
    "eucm",
    "omnidirectional",
)


def describe_validation_error(exc: ValidationError, data: Any) -> str:
    """Pydantic's error locations in a rig document as 'camera '<name>' (field): message'."""
    cameras = data.get("cameras") if isinstance(data, dict) else None
    parts = []
    for err in exc.errors():
        loc = list(err["loc"])
        where = ".".join(str(x) for x in loc) or "rig"
        if len(loc) >= 2 and loc[0] == "cameras" and isinstance(loc[1], int):
            entry = cameras[loc[1]] if isinstance(cameras, (list, tuple)) and loc[1] < len(cameras) else None
            name = entry.get("name") if isinstance(entry, dict) else None
            field = ".".join(str(x) for x in loc[2:] if x not in _MODEL_TYPES) or "entry"
            where = f"camera '{name}' ({field})" if name else f"camera #{loc[1]} ({field})"
        parts.append(f"{where}: {error_message(err)}")
    return "; ".join(parts)


def error_message(error: Any) -> str:
    """One pydantic error's message; a value that is not finite is said to be so, whatever the field's bound."""
    value = error.get("input")
    if isinstance(value, float) and not math.isfinite(value):
        return f"not finite (got {value})"
    return str(error["msg"]).removeprefix("Value error, ")
