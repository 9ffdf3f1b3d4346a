"""How a [`Rig`][fisheye_infer.cameras.rig.Rig] is built: the bodies of its ``from_*`` and ``load`` class methods.

Each function takes the class it builds (``cls``) first, so that the class methods stay the public face,
with their documentation, and this module holds what they do: read the calibration and extrinsics files
(through ``rig_files`` and ``calibration_files``), assemble the cameras, and validate the document with
errors that name the camera and field.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ValidationError

from fisheye_infer.cameras.carla_poses import Convention
from fisheye_infer.cameras.default_rigs import FISHEYE3DOD_CAMERAS
from fisheye_infer.cameras.kalibr_camchain import TrustChain
from fisheye_infer.cameras.rig_files import (
    describe_validation_error,
    is_pinhole_list,
    pinhole_list_cameras,
    read_lidar2cam_json,
    read_ocam,
    read_rig_document,
    read_sensor_metadata_poses,
)
from fisheye_infer.errors import RigError

if TYPE_CHECKING:
    from fisheye_infer.cameras.rig import Rig

__all__ = [
    "load",
    "from_calibration",
    "from_cameras",
    "from_dict",
    "from_ocam_extrinsics",
    "from_pinhole_list",
    "from_sensor_metadata",
]


def from_dict(cls: type[Rig], data: Any, source: str) -> Rig:
    """``Rig.from_dict``: validate a rig document, every problem named by camera and field."""
    try:
        return cls.model_validate(data)
    except ValidationError as exc:
        raise RigError(f"{source}: " + describe_validation_error(exc, data)) from None


def from_cameras(
    cls: type[Rig],
    models: dict[str, Any],
    cam2lidar: dict[str, np.ndarray],
    order: Sequence[str] | None,
    name: str,
) -> Rig:
    """``Rig.from_cameras``: assemble a rig from per-camera models and cam2lidar matrices, in ``order``."""
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


def from_ocam_extrinsics(
    cls: type[Rig],
    calib: str | Path,
    lidar2cam_json: str | Path,
    order: Sequence[str] | None,
    fov: float,
    name: str | None,
) -> Rig:
    """``Rig.from_ocam_extrinsics``: one OCam file shared by all cameras + their lidar2cam JSON."""
    model = read_ocam(calib, fov)
    cam2lidar = read_lidar2cam_json(lidar2cam_json)
    if order is None:
        order = FISHEYE3DOD_CAMERAS if set(cam2lidar) == set(FISHEYE3DOD_CAMERAS) else list(cam2lidar)
    name = name or Path(lidar2cam_json).parent.name
    return cls.from_cameras({c: model for c in cam2lidar}, cam2lidar, order, name=name)


def from_sensor_metadata(
    cls: type[Rig],
    vehicle_dir: str | Path,
    calib: str | Path,
    cameras: Sequence[str],
    frame_id: str | None,
    convention: Convention,
    fov: float,
) -> Rig:
    """``Rig.from_sensor_metadata``: the rig of one Fisheye3DOD frame from its sensor metadata."""
    root = Path(vehicle_dir)
    model = read_ocam(calib, fov)
    frame_id, cam2lidar = read_sensor_metadata_poses(root, cameras, frame_id, convention)
    return cls.from_cameras(
        {c: model for c in cameras}, cam2lidar, cameras, name=f"{root.parent.name}/{root.name}@{frame_id}"
    )


def from_calibration(
    cls: type[Rig],
    files: Sequence[str | Path],
    extrinsics: str | Path,
    format: str | None,
    names: Sequence[str] | None,
    name: str | None,
    trust_chain: TrustChain | None,
) -> Rig:
    """``Rig.from_calibration``: cameras from calibration files, placed in the lidar frame."""
    from fisheye_infer.cameras.calibration_files import place_cameras, read_calibrations

    groups = read_calibrations(files, format, names, trust_chain)
    cam2lidar = place_cameras(groups, read_lidar2cam_json(extrinsics), str(extrinsics))
    models = {c.name: c.model for _, cams in groups for c in cams}
    return cls.from_cameras(models, cam2lidar, name=name or Path(files[0]).stem)


def load(cls: type[Rig], path: str | Path) -> Rig:
    """``Rig.load``: a rig file, or a pinhole camera list."""
    path = Path(path)
    data = read_rig_document(path)
    if is_pinhole_list(data):
        return cls.from_pinhole_list(data, source=f"rig file {path}", name=path.parent.name or path.stem)
    return cls.from_dict(data, source=f"rig file {path}")


def from_pinhole_list(cls: type[Rig], data: dict[str, Any], source: str, name: str) -> Rig:
    """``Rig.from_pinhole_list``: distortion-free cameras given as ``K`` and ``lidar2cam``."""
    models, cam2lidar = pinhole_list_cameras(data, source)
    return cls.from_cameras(models, cam2lidar, name=name)


def _as_dict(model: Any) -> Any:
    return model.model_dump() if isinstance(model, BaseModel) else model
