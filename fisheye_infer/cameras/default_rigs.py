"""The rigs shipped with the package, the dataset camera orders, and the rig a user names.

``default_rig`` is Fisheye3DOD's four-camera OCam rig (``data/rig-fisheye3dod``), ``pinhole_rig`` the
six-camera pinhole rig of the pinhole baselines (``data/rig-pinhole6``), and ``resolve_rig`` turns what a
user types (nothing, ``default``, a rig file or a calibration folder) into a rig.
"""

from __future__ import annotations

from functools import lru_cache
from importlib import resources
from pathlib import Path
from typing import TYPE_CHECKING

from fisheye_infer.errors import RigError

if TYPE_CHECKING:
    from fisheye_infer.cameras.rig import Rig

__all__ = ["FISHEYE3DOD_CAMERAS", "PINHOLE_CAMERAS", "default_rig", "pinhole_rig", "resolve_rig"]

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
    from fisheye_infer.cameras.rig import Rig

    base = resources.files("fisheye_infer") / "data" / "rig-fisheye3dod"
    with resources.as_file(base) as folder:
        return Rig.from_ocam_extrinsics(folder / "calib_results.txt", folder / "lidar2cam.json", name="fisheye3dod")


def pinhole_rig() -> Rig:
    """The six-camera pinhole rig shipped with the package (``rig-pinhole6``): the pinhole baselines' 1280x720
    ideal 90-degree cameras in their input order, with constructed nuScenes-like extrinsics."""
    from fisheye_infer.cameras.rig import Rig

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
    from fisheye_infer.cameras.rig import Rig

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
