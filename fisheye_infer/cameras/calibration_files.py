"""Camera calibrations as the tools robot teams use write them, read into the project's camera models.

    cameras = read_calibration("camchain.yaml")        # format recognised from the content
    cameras = read_calibration("left.yaml", "ros")      # or named

- ``kalibr``: a Kalibr camchain (``kalibr_camchain``), also with the ``%YAML:1.0`` header OpenVINS ships
  its camchains with. Its chain (``T_cn_cnm1``) or its IMU poses (``T_cam_imu``, ``T_imu_cam``) give every
  camera's pose in ``cam0``'s frame; where both are there and disagree, ``trust_chain`` says which to use.
- ``ros``: a ROS ``CameraInfo`` YAML (``camera_calibration_parsers``: ``image_width``, ``camera_matrix``,
  ``distortion_model``, ``distortion_coefficients``): ``plumb_bob``, ``rational_polynomial``, ``equidistant``;
  without ``distortion_model`` (older files) ``plumb_bob``, as ROS reads them.
- ``opencv``: a ``cv::FileStorage`` file, YAML or XML, of OpenCV's calibration sample (``camera_matrix``,
  ``distortion_coefficients``, ``image_width``, ``image_height``, ``fisheye_model``): ``cv::fisheye``
  (four coefficients) or the pinhole model (4, 5 or 8).
- ``ocam``: an OCamCalib ``calib_results.txt``, one camera per file, named by its folder where the file
  keeps OCamCalib's name (``front/calib_results.txt`` is camera ``front``), by its file name otherwise.

Distortion conventions: Kalibr's ``equidistant``, ROS's ``equidistant`` and ``cv::fisheye`` share
``k1..k4`` of ``theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)`` (``KannalaBrandt.k``); Kalibr's
``radtan`` ``[k1, k2, r1, r2]`` is OpenCV's ``[k1, k2, p1, p2]``. A camera whose model cannot be represented
is refused with the reason. Wide-angle cameras get a ``fov`` covering what their image shows
(``image_fov``, never more than the model projects), as none of these formats states one; OCam cameras get
220 degrees, Fisheye3DOD's, as ``fisheye-infer rig convert`` gives them by default.

Every file is read through ``text_input``: a binary file is "not a calibration file", YAML anchors and
aliases are refused, and a value that is not finite (YAML's ``.nan``, OpenCV's ``.Nan``) is named as such.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np

from fisheye_infer.cameras.calibration_values import (
    POSE_TOLERANCE_DEG,
    POSE_TOLERANCE_MM,
    CalibratedCamera,
    floats,
    k_and_d,
    matrix,
    pose_difference,
)
from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.field_of_view import image_fov
from fisheye_infer.cameras.kalibr_camchain import TrustChain, camchain_cameras, is_camchain
from fisheye_infer.cameras.text_input import AliasRefused, load_yaml, read_text, short
from fisheye_infer.errors import CameraModelError, RigError

__all__ = [
    "FORMATS",
    "CalibratedCamera",
    "detect_format",
    "image_fov",
    "place_cameras",
    "read_calibration",
    "read_calibrations",
]

#: The calibration formats ``read_calibration`` reads.
FORMATS: Final = ("kalibr", "ros", "opencv", "ocam")
#: How OCamCalib's ``calib_results.txt`` begins.
_OCAM_HEADER: Final = "#polynomial coefficients for the DIRECT mapping function"
#: What names a file a calibration file in the refusals of one that is not.
_WHAT: Final = "a calibration file"
#: OpenCV's YAML directive (``%YAML:1.0``), which YAML parsers other than OpenCV's refuse.
_OPENCV_DIRECTIVE = re.compile(r"\A\s*%YAML:[0-9.]+[ \t]*(#[^\n]*)?\n")
#: An OpenCV FileStorage XML file.
_OPENCV_XML = re.compile(r"\A\s*(<\?xml[^>]*\?>\s*)?<opencv_storage>")


def detect_format(path: str | Path) -> str:
    """Which of ``FORMATS`` a file is, from its content.

    Args:
        path (str | Path): A calibration file.

    Returns:
        str: ``"kalibr"``, ``"ros"``, ``"opencv"`` or ``"ocam"``.

    Raises:
        RigError: The file is missing, not text or none of the formats.
    """
    path = Path(path)
    text = read_text(path, _WHAT)
    if text.lstrip().startswith(_OCAM_HEADER):
        return "ocam"
    if _OPENCV_XML.match(text):
        return "opencv"
    opencv = text.lstrip().startswith("%YAML") or "!!opencv-matrix" in text
    try:
        data = _yaml(path, text)
    except AliasRefused:
        raise
    except RigError:
        if opencv:  # OpenCV's own YAML: its matrix tags are no YAML another parser reads
            return "opencv"
        raise
    if is_camchain(data):
        return "kalibr"
    if opencv:
        return "opencv"
    if isinstance(data, dict) and "camera_matrix" in data and "image_width" in data:
        return "ros"
    raise RigError(
        f"{path}: not a calibration this reads (a Kalibr camchain, a ROS CameraInfo YAML, an OpenCV "
        "FileStorage file or an OCamCalib calib_results.txt); name the format with --format"
    )


def read_calibration(
    path: str | Path, format: str | None = None, trust_chain: TrustChain | None = None
) -> list[CalibratedCamera]:
    """The cameras of a calibration file, in file order.

    Args:
        path (str | Path): The file.
        format (str | None): ``"kalibr"``, ``"ros"``, ``"opencv"`` or ``"ocam"``; None: recognised from the
            content ([`detect_format`][fisheye_infer.cameras.calibration_files.detect_format]).
        trust_chain (TrustChain | None): For a Kalibr camchain carrying both ``T_cn_cnm1`` and ``T_cam_imu``,
            which places the cameras where the two disagree (``"cn_cnm1"`` or ``"imu"``); None: neither, a
            disagreement is refused with its size.

    Returns:
        list[CalibratedCamera]: Each camera's name, model and, for a camchain, its pose in the first camera's
            frame.

    Raises:
        RigError: The file is missing, not text or not of the format, a value is missing or not finite, or a
            camera model cannot be represented (the reason named).

    Examples:
        ```python
        from fisheye_infer.cameras.calibration_files import read_calibration

        for cam in read_calibration("camchain.yaml"):         # format recognised from the content
            print(cam.name, cam.model.type, cam.model.width, cam.model.height)
        left = read_calibration("left.yaml", "ros")[0]         # a ROS CameraInfo YAML
        ```
    """
    path = Path(path)
    kind = format or detect_format(path)
    if kind == "kalibr":
        return camchain_cameras(path, _yaml(path, read_text(path, _WHAT)), trust_chain)
    if kind == "ros":
        return [_ros(path)]
    if kind == "opencv":
        return [_opencv(path)]
    if kind == "ocam":
        return [_ocam(path)]
    raise RigError(f"{path}: format {short(kind)} is not one of {', '.join(FORMATS)}")


def read_calibrations(
    files: Sequence[str | Path],
    format: str | None = None,
    names: Sequence[str] | None = None,
    trust_chain: TrustChain | None = None,
) -> list[tuple[str, list[CalibratedCamera]]]:
    """Each file and its cameras (``read_calibration``), the cameras renamed in file order by ``names``.

    Args:
        files (Sequence[str | Path]): Calibration files.
        format (str | None): Their format; None: recognised per file.
        names (Sequence[str] | None): New names, one per camera over all files in order; None keeps the files'.
        trust_chain (TrustChain | None): As for
            [`read_calibration`][fisheye_infer.cameras.calibration_files.read_calibration].

    Returns:
        list[tuple[str, list[CalibratedCamera]]]: (file, its cameras) per file, in order.

    Raises:
        RigError: As ``read_calibration``, or a number of ``names`` other than the number of cameras.
    """
    per_file = [read_calibration(f, format, trust_chain) for f in files]
    if names is not None:
        count = sum(len(cams) for cams in per_file)
        if len(names) != count:
            raise RigError(f"names: {len(names)} given for {count} camera(s) in {', '.join(map(str, files))}")
        renamed = iter(names)
        per_file = [[replace(cam, name=next(renamed)) for cam in cams] for cams in per_file]
    return list(zip(map(str, files), per_file))


def place_cameras(
    files: Sequence[tuple[str, list[CalibratedCamera]]], given: dict[str, np.ndarray], source: str
) -> dict[str, np.ndarray]:
    """cam2lidar of every camera of ``files`` (each file and the cameras read from it), from ``given``
    (cam2lidar by camera name, read from ``source``).

    A file's chained cameras (a Kalibr camchain) are placed from the first of them in ``given``, its anchor;
    each file from its own. A chained camera also in ``given`` must agree with the chain
    (``POSE_TOLERANCE_MM``, ``POSE_TOLERANCE_DEG``: 1 mm, 0.06 degrees). Every other camera needs its own
    entry in ``given``.

    Args:
        files (Sequence[tuple[str, list[CalibratedCamera]]]): What
            [`read_calibrations`][fisheye_infer.cameras.calibration_files.read_calibrations] returns.
        given (dict[str, np.ndarray]): Camera name -> 4x4 cam2lidar, metres.
        source (str): What error messages call ``given`` (its file).

    Returns:
        dict[str, np.ndarray]: Camera name -> (4, 4) float64 cam2lidar for every camera of ``files``.

    Raises:
        RigError: A camera named twice, a camchain none of whose cameras is in ``given``, a chained camera
            whose given pose disagrees with the chain, or a camera without a pose.
    """
    seen: dict[str, str] = {}
    for file, cameras in files:
        for cam in cameras:
            if cam.name in seen:
                where = file if seen[cam.name] == file else f"{seen[cam.name]} and {file}"
                raise RigError(f"camera {short(cam.name)}: named twice ({where}); name the cameras with --names")
            seen[cam.name] = file
    cam2lidar = {name: given[name] for name in seen if name in given}
    for file, cameras in files:
        chained = [(cam, cam.cam2first) for cam in cameras if cam.cam2first is not None]
        if not chained:
            continue
        anchor = next(((cam, pose) for cam, pose in chained if cam.name in given), None)
        if anchor is None:
            raise RigError(
                f"extrinsics {source}: none of the chained cameras of {file} "
                f"({', '.join(cam.name for cam, _ in chained)}) is in it; give lidar2cam of at least one"
            )
        first2lidar = given[anchor[0].name] @ np.linalg.inv(anchor[1])
        for cam, pose in chained:
            placed = first2lidar @ pose
            if cam.name in given:
                mm, deg = pose_difference(given[cam.name], placed)
                if mm > POSE_TOLERANCE_MM or deg > POSE_TOLERANCE_DEG:
                    raise RigError(
                        f"camera '{cam.name}': the extrinsics in {source} and the camchain {file} disagree by "
                        f"{mm:.1f} mm and {deg:.2f} degrees; give one camera's lidar2cam, or ones that agree"
                    )
            cam2lidar[cam.name] = placed
    missing = [name for name in seen if name not in cam2lidar]
    if missing:
        raise RigError(f"extrinsics {source}: no lidar2cam for camera(s) {', '.join(missing)}")
    return cam2lidar


def _yaml(path: Path, text: str) -> Any:
    """The YAML document of a calibration file; OpenCV's ``%YAML:1.0`` directive, which other YAML readers refuse,
    is dropped."""
    return load_yaml(_OPENCV_DIRECTIVE.sub("", text, count=1), path)


# -- ROS CameraInfo ----------------------------------------------------------------------------------


def _ros(path: Path) -> CalibratedCamera:
    data = _yaml(path, read_text(path, _WHAT))
    if not isinstance(data, dict):
        kind = type(data).__name__
        raise RigError(f"{path}: expected a ROS CameraInfo YAML (image_width, camera_matrix, ...), got a {kind}")
    name = str(data.get("camera_name") or path.stem)
    label = f"{path}: camera {short(name)}"
    k = matrix(_ros_data(data, "camera_matrix", label), (3, 3), f"{label} (camera_matrix)")
    d = floats(_ros_data(data, "distortion_coefficients", label), None, f"{label} (distortion_coefficients)")
    size = {"width": _int(data, "image_width", label), "height": _int(data, "image_height", label)}
    model = k_and_d(k, d, str(data.get("distortion_model", "plumb_bob")), label, size)
    return CalibratedCamera(name, model)


def _ros_data(data: dict[str, Any], key: str, label: str) -> Any:
    node = data.get(key)
    if not isinstance(node, dict) or "data" not in node:
        raise RigError(f"{label} ({key}): expected a matrix with rows, cols and data")
    return node["data"]


def _int(data: dict[str, Any], key: str, label: str) -> int:
    value = data.get(key)
    if not isinstance(value, int) or isinstance(value, bool) or value <= 0:
        raise RigError(f"{label} ({key}): expected a positive integer, got {short(value)}")
    return value


# -- OpenCV FileStorage ------------------------------------------------------------------------------


def _opencv(path: Path) -> CalibratedCamera:
    label = f"{path}: camera '{path.stem}'"
    read_text(path, _WHAT)  # a binary file is refused before OpenCV parses it
    try:
        storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
        opened = storage.isOpened()
    except (cv2.error, SystemError) as exc:
        raise RigError(f"{path}: not an OpenCV FileStorage file OpenCV can read ({_cv_reason(exc)})") from None
    if not opened:
        raise RigError(f"{path}: OpenCV cannot open it as a FileStorage file")
    try:
        k = storage.getNode("camera_matrix").mat()
        d = storage.getNode("distortion_coefficients").mat()
        width, height = (storage.getNode(n).real() for n in ("image_width", "image_height"))
        fisheye = storage.getNode("fisheye_model")
        is_fisheye = None if fisheye.empty() else fisheye.real()
    except (cv2.error, SystemError) as exc:
        raise RigError(f"{label}: OpenCV cannot read its nodes ({_cv_reason(exc)})") from None
    finally:
        storage.release()
    if k is None or d is None:
        raise RigError(f"{label}: expected camera_matrix and distortion_coefficients (OpenCV's calibration sample)")
    for key, value in (("image_width", width), ("image_height", height)):
        if not math.isfinite(value):
            raise RigError(f"{label} ({key}): not finite (got {value})")
        if value <= 0 or value != int(value):
            raise RigError(f"{label} ({key}): expected a positive integer, got {value}")
    if k.shape != (3, 3):
        raise RigError(f"{label} (camera_matrix): expected a 3x3 matrix, got shape {k.shape}")
    coeffs = d.astype(np.float64).ravel().tolist()
    if is_fisheye is None:
        if len(coeffs) == 4:
            raise RigError(
                f"{label} (fisheye_model): missing, and 4 coefficients fit both cv::fisheye (k1..k4) and the "
                "pinhole model (k1, k2, p1, p2); add fisheye_model: 1 or 0"
            )
        is_fisheye = 0.0
    size = {"width": int(width), "height": int(height)}
    model = k_and_d(k.astype(np.float64), coeffs, "fisheye" if is_fisheye else "opencv", label, size)
    return CalibratedCamera(path.stem, model)


def _cv_reason(exc: BaseException) -> str:
    reason = exc.__cause__ or exc.__context__ or exc
    text = " ".join(str(getattr(reason, "err", "") or reason).split())
    return text[:200] or type(exc).__name__


# -- OCamCalib -------------------------------------------------------------------------------------


def _ocam(path: Path) -> CalibratedCamera:
    try:
        model = OCamModel.parse(read_text(path, _WHAT), source=str(path))
    except CameraModelError as exc:
        raise RigError(str(exc)) from exc
    return CalibratedCamera(path.parent.name if path.stem == "calib_results" else path.stem, model)
