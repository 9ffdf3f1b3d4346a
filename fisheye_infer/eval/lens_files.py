"""The lens files of the Fisheye3DOD layout: OCam's ``calib_results.txt`` (at the root, or a camera's own in its
folder) and ``camera_model.json`` (a camera's lens of a model OCam cannot express, as a rig file holds it)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from pydantic import TypeAdapter, ValidationError

from fisheye_infer.cameras.camera_models import AnyCameraModel, OCamModel
from fisheye_infer.errors import CameraModelError, DatasetError

__all__ = ["CAMERA_MODEL_FILE", "read_lens", "camera_lens"]

#: A fisheye camera's own lens as JSON, in its folder, for a model that ``calib_results.txt`` (OCam) cannot express.
CAMERA_MODEL_FILE = "camera_model.json"


def read_lens(path: Path, fov: float) -> OCamModel:
    try:
        return OCamModel.from_file(path, fov=fov)
    except CameraModelError as exc:
        raise DatasetError(str(exc)) from exc


def camera_lens(folder: Path, root_lens: OCamModel | None, fov: float, what: str) -> Any:
    """A fisheye camera's lens: its folder's ``camera_model.json`` (a model OCam cannot express) or
    ``calib_results.txt``, else the dataset root's ``calib_results.txt``."""
    model_file = folder / CAMERA_MODEL_FILE
    if model_file.is_file():
        try:
            return TypeAdapter(AnyCameraModel).validate_json(model_file.read_bytes())
        except (OSError, ValidationError) as exc:
            raise DatasetError(f"{what}: {model_file} is not a camera model ({str(exc).splitlines()[0]})") from None
    own = folder / "calib_results.txt"
    if own.is_file():
        return read_lens(own, fov)
    if root_lens is None:
        raise DatasetError(f"{what}: calib_results.txt not found, neither in {folder} nor at the dataset root")
    return root_lens
