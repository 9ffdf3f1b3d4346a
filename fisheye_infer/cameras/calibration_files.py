"""Camera calibrations as the tools robot teams use write them, read into the project's camera models.

    cameras = read_calibration("camchain.yaml")        # format recognised from the content
    cameras = read_calibration("left.yaml", "ros")      # or named

- ``kalibr``: a Kalibr camchain (``cam0``, ``cam1``, ... with ``camera_model``, ``intrinsics``,
  ``distortion_model``, ``distortion_coeffs``, ``resolution`` and, from ``cam1`` on, ``T_cn_cnm1``):
  ``pinhole`` with ``radtan``, ``equidistant`` or ``none``; ``omni`` with ``radtan`` or ``none``; ``ds`` and
  ``eucm`` with ``none``. The chain gives every camera's pose in ``cam0``'s frame.
- ``ros``: a ROS ``CameraInfo`` YAML (``camera_calibration_parsers``: ``image_width``, ``camera_matrix``,
  ``distortion_model``, ``distortion_coefficients``): ``plumb_bob``, ``rational_polynomial``, ``equidistant``.
- ``opencv``: a ``cv::FileStorage`` file of OpenCV's calibration sample (``camera_matrix``,
  ``distortion_coefficients``, ``image_width``, ``image_height``, ``fisheye_model``): ``cv::fisheye``
  (four coefficients) or the pinhole model (4, 5 or 8).
- ``ocam``: an OCamCalib ``calib_results.txt``, one camera per file, named by its folder where the file
  keeps OCamCalib's name (``front/calib_results.txt`` is camera ``front``), by its file name otherwise.

Distortion conventions: Kalibr's ``equidistant``, ROS's ``equidistant`` and ``cv::fisheye`` share
``k1..k4`` of ``theta_d = theta (1 + k1 theta^2 + ... + k4 theta^8)`` (``KannalaBrandt.k``); Kalibr's
``radtan`` ``[k1, k2, r1, r2]`` is OpenCV's ``[k1, k2, p1, p2]``. A camera whose model cannot be represented
is refused with the reason. Wide-angle cameras get a ``fov`` covering what their image shows
(``image_fov``), as none of these formats states one; OCam cameras get 220 degrees, Fisheye3DOD's, as
``fisheye-infer rig convert`` gives them by default.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Final

import cv2
import numpy as np
import yaml
from pydantic import ValidationError

from fisheye_infer.cameras.camera_models import (
    DistortedPinhole,
    DoubleSphere,
    ExtendedUnified,
    KannalaBrandt,
    OCamModel,
    Omnidirectional,
    Pinhole,
    incidence_angle,
)
from fisheye_infer.errors import CameraModelError, RigError

__all__ = ["FORMATS", "CalibratedCamera", "detect_format", "image_fov", "read_calibration"]

#: The calibration formats ``read_calibration`` reads.
FORMATS: Final = ("kalibr", "ros", "opencv", "ocam")
#: How OCamCalib's ``calib_results.txt`` begins.
_OCAM_HEADER: Final = "#polynomial coefficients for the DIRECT mapping function"


@dataclass(frozen=True)
class CalibratedCamera:
    """One camera of a calibration file: its name, model and, where the file chains cameras (Kalibr),
    its pose in the first camera's frame (4x4, camera to first camera); None where the file has none."""

    name: str
    model: Any
    cam2first: np.ndarray | None = None


def detect_format(path: str | Path) -> str:
    """Which of ``FORMATS`` a file is, from its content; a ``RigError`` when none fits."""
    path = Path(path)
    text = _read(path)
    if text.lstrip().startswith(_OCAM_HEADER):
        return "ocam"
    if text.lstrip().startswith("%YAML:") or "!!opencv-matrix" in text:
        return "opencv"
    data = _yaml(path, text)
    if isinstance(data, dict) and any(isinstance(v, dict) and "camera_model" in v for v in data.values()):
        return "kalibr"
    if isinstance(data, dict) and "camera_matrix" in data and "distortion_model" in data:
        return "ros"
    raise RigError(
        f"{path}: not a calibration this reads (a Kalibr camchain, a ROS CameraInfo YAML, an OpenCV "
        "FileStorage file or an OCamCalib calib_results.txt); name the format with --format"
    )


def read_calibration(path: str | Path, format: str | None = None) -> list[CalibratedCamera]:
    """The cameras of a calibration file, in file order (``format``: one of ``FORMATS``, default: detected)."""
    path = Path(path)
    kind = format or detect_format(path)
    if kind == "kalibr":
        return _kalibr(path)
    if kind == "ros":
        return [_ros(path)]
    if kind == "opencv":
        return [_opencv(path)]
    if kind == "ocam":
        return [_ocam(path)]
    raise RigError(f"{path}: format {kind!r} is not one of {', '.join(FORMATS)}")


def image_fov(model: Any, directions: int = 72, steps: int = 400) -> float:
    """The full field of view (degrees) that ``model``'s image shows: twice the largest incidence angle of the
    rays through its pixels, sampled from the principal point out to the image border in ``directions``
    directions. A pixel that is not the image of a ray (outside a circular fisheye's image circle, or where a
    distortion polynomial has turned back) is left out: its unprojection does not project back onto it."""
    w, h = model.width, model.height
    angle = np.linspace(0.0, 2 * math.pi, directions, endpoint=False)
    dx, dy = np.cos(angle), np.sin(angle)
    with np.errstate(divide="ignore"):  # the distance to the border along each direction
        reach = np.minimum(
            np.where(dx > 0, (w - 1 - model.cx) / dx, np.where(dx < 0, -model.cx / dx, np.inf)),
            np.where(dy > 0, (h - 1 - model.cy) / dy, np.where(dy < 0, -model.cy / dy, np.inf)),
        )
    t = np.linspace(0.0, 1.0, steps)[None, :] * reach[:, None]
    pixels = np.stack([model.cx + t * dx[:, None], model.cy + t * dy[:, None]], axis=-1).reshape(-1, 2)
    rays = model.unproject(pixels)
    with np.errstate(invalid="ignore"):
        back = model.project(np.nan_to_num(rays))[0]
    on_sphere = np.isfinite(rays).all(axis=1) & (np.abs(back - pixels).max(axis=1) < 0.01)
    if not on_sphere.any():
        raise RigError(f"{type(model).__name__}: no pixel of the image is the image of a ray")
    return round(2 * math.degrees(float(incidence_angle(rays[on_sphere]).max())), 3)


# -- Kalibr ------------------------------------------------------------------------------------------

_KALIBR_MODELS = {
    ("pinhole", "radtan"): "distorted_pinhole",
    ("pinhole", "equidistant"): "kannala_brandt",
    ("pinhole", "none"): "pinhole",
    ("omni", "radtan"): "omnidirectional",
    ("omni", "none"): "omnidirectional",
    ("ds", "none"): "double_sphere",
    ("eucm", "none"): "eucm",
}
_KALIBR_INTRINSICS = {"pinhole": 4, "omni": 5, "ds": 6, "eucm": 6}


def _kalibr(path: Path) -> list[CalibratedCamera]:
    data = _yaml(path, _read(path))
    keys = (
        [k for k in data if isinstance(data[k], dict) and "camera_model" in data[k]] if isinstance(data, dict) else []
    )
    if not keys:
        raise RigError(f"{path}: no camera of a Kalibr camchain (cam0, cam1, ... with camera_model)")
    cameras = []
    pose = np.eye(4)
    for i, key in enumerate(keys):
        entry = data[key]
        label = f"{path}: camera '{key}'"
        model = _kalibr_model(entry, label)
        if i > 0:
            chain = _matrix(entry.get("T_cn_cnm1"), (4, 4), f"{label} (T_cn_cnm1)")
            pose = pose @ np.linalg.inv(chain)  # camera n to camera 0 = (cam n-1 to 0) (cam n to n-1)
        cameras.append(CalibratedCamera(key, model, pose.copy()))
    return cameras


def _kalibr_model(entry: dict[str, Any], label: str) -> Any:
    camera, distortion = str(entry.get("camera_model")), str(entry.get("distortion_model", "none"))
    kind = _KALIBR_MODELS.get((camera, distortion))
    if kind is None:
        supported = ", ".join(f"{c}-{d}" for c, d in _KALIBR_MODELS)
        raise RigError(
            f"{label}: camera_model {entry.get('camera_model')!r} with distortion_model {distortion!r} cannot be "
            f"represented (supported: {supported})"
        )
    intrinsics = _floats(entry.get("intrinsics"), _KALIBR_INTRINSICS[camera], f"{label} (intrinsics)")
    coeffs = _floats(entry.get("distortion_coeffs", []), None, f"{label} (distortion_coeffs)")
    resolution = _floats(entry.get("resolution"), 2, f"{label} (resolution)")
    size = {"width": int(resolution[0]), "height": int(resolution[1])}
    if kind in ("distorted_pinhole", "kannala_brandt", "omnidirectional") and distortion != "none" and len(coeffs) != 4:
        raise RigError(f"{label} (distortion_coeffs): {distortion} takes 4 coefficients, got {len(coeffs)}")
    if camera == "pinhole":
        fx, fy, cx, cy = intrinsics
        if kind == "pinhole":
            return _build(Pinhole, label, fx=fx, fy=fy, cx=cx, cy=cy, **size)
        if kind == "distorted_pinhole":
            return _build(DistortedPinhole, label, fx=fx, fy=fy, cx=cx, cy=cy, distortion=tuple(coeffs), **size)
        return _wide(KannalaBrandt, label, fx=fx, fy=fy, cx=cx, cy=cy, k=tuple(coeffs), **size)
    if camera == "omni":
        xi, fx, fy, cx, cy = intrinsics
        d = tuple(coeffs) if distortion == "radtan" else (0.0, 0.0, 0.0, 0.0)
        return _wide(Omnidirectional, label, fx=fx, fy=fy, cx=cx, cy=cy, xi=xi, distortion=d, **size)
    if camera == "ds":
        xi, alpha, fx, fy, cx, cy = intrinsics
        return _wide(DoubleSphere, label, fx=fx, fy=fy, cx=cx, cy=cy, xi=xi, alpha=alpha, **size)
    alpha, beta, fx, fy, cx, cy = intrinsics
    return _wide(ExtendedUnified, label, fx=fx, fy=fy, cx=cx, cy=cy, alpha=alpha, beta=beta, **size)


# -- ROS CameraInfo ----------------------------------------------------------------------------------


def _ros(path: Path) -> CalibratedCamera:
    data = _yaml(path, _read(path))
    label = f"{path}: camera '{data.get('camera_name') or path.stem}'"
    k = _matrix(_ros_data(data, "camera_matrix", label), (3, 3), f"{label} (camera_matrix)")
    d = _floats(_ros_data(data, "distortion_coefficients", label), None, f"{label} (distortion_coefficients)")
    size = {"width": _int(data, "image_width", label), "height": _int(data, "image_height", label)}
    model = _k_and_d(k, d, str(data.get("distortion_model")), label, size)
    return CalibratedCamera(str(data.get("camera_name") or path.stem), model)


def _ros_data(data: dict[str, Any], key: str, label: str) -> Any:
    node = data.get(key)
    if not isinstance(node, dict) or "data" not in node:
        raise RigError(f"{label} ({key}): expected a matrix with rows, cols and data")
    return node["data"]


# -- OpenCV FileStorage ------------------------------------------------------------------------------


def _opencv(path: Path) -> CalibratedCamera:
    label = f"{path}: camera '{path.stem}'"
    storage = cv2.FileStorage(str(path), cv2.FILE_STORAGE_READ)
    if not storage.isOpened():
        raise RigError(f"{path}: OpenCV cannot open it as a FileStorage file")
    try:
        k = storage.getNode("camera_matrix").mat()
        d = storage.getNode("distortion_coefficients").mat()
        width, height = (storage.getNode(n).real() for n in ("image_width", "image_height"))
        fisheye = storage.getNode("fisheye_model")
        is_fisheye = None if fisheye.empty() else bool(fisheye.real())
    finally:
        storage.release()
    if k is None or d is None:
        raise RigError(f"{label}: expected camera_matrix and distortion_coefficients (OpenCV's calibration sample)")
    if not width or not height:
        raise RigError(f"{label}: expected image_width and image_height")
    coeffs = d.ravel().tolist()
    if is_fisheye is None:
        if len(coeffs) == 4:
            raise RigError(
                f"{label} (fisheye_model): missing, and 4 coefficients fit both cv::fisheye (k1..k4) and the "
                "pinhole model (k1, k2, p1, p2); add fisheye_model: 1 or 0"
            )
        is_fisheye = False
    size = {"width": int(width), "height": int(height)}
    return CalibratedCamera(path.stem, _k_and_d(k, coeffs, "fisheye" if is_fisheye else "opencv", label, size))


# -- OCamCalib -------------------------------------------------------------------------------------


def _ocam(path: Path) -> CalibratedCamera:
    try:
        model = OCamModel.parse(_read(path), source=str(path))
    except CameraModelError as exc:
        raise RigError(str(exc)) from exc
    return CalibratedCamera(path.parent.name if path.stem == "calib_results" else path.stem, model)


# -- shared ------------------------------------------------------------------------------------------


def _k_and_d(k: np.ndarray, d: list[float], model: str, label: str, size: dict[str, int]) -> Any:
    """A model from a camera matrix and OpenCV-ordered coefficients: ``plumb_bob``, ``rational_polynomial``,
    ``opencv`` (4, 5 or 8) and ``equidistant``/``fisheye`` (4)."""
    if k[0, 1] != 0 or k[1, 0] != 0 or not np.allclose(k[2], (0, 0, 1)):
        raise RigError(f"{label} (camera_matrix): expected [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], got {k.tolist()}")
    intrinsics = {"fx": k[0, 0], "fy": k[1, 1], "cx": k[0, 2], "cy": k[1, 2], **size}
    if model in ("equidistant", "fisheye"):
        if len(d) != 4:
            raise RigError(f"{label}: the {model} model takes 4 coefficients (k1..k4), got {len(d)}")
        return _wide(KannalaBrandt, label, k=tuple(d), **intrinsics)
    expected = {"plumb_bob": (5,), "rational_polynomial": (8,), "opencv": (4, 5, 8)}.get(model)
    if expected is None:
        raise RigError(
            f"{label} (distortion_model): {model!r} cannot be represented "
            "(supported: plumb_bob, rational_polynomial, equidistant)"
        )
    if len(d) not in expected:
        raise RigError(f"{label}: {model} takes {' or '.join(map(str, expected))} coefficients, got {len(d)}")
    if not any(d):
        return _build(Pinhole, label, **intrinsics)
    return _build(DistortedPinhole, label, distortion=tuple(d), **intrinsics)


def _wide(cls: type, label: str, **fields: Any) -> Any:
    """A wide-angle model with the field of view its image shows."""
    model = _build(cls, label, **{**fields, "fov": 360.0})
    return _build(cls, label, **{**fields, "fov": min(image_fov(model), 360.0)})


def _build(cls: type, label: str, **fields: Any) -> Any:
    try:
        return cls(**fields)
    except ValidationError as exc:
        problems = "; ".join(f"{'.'.join(map(str, e['loc']))}: {e['msg']}" for e in exc.errors())
        raise RigError(f"{label}: {problems}") from None


def _read(path: Path) -> str:
    try:
        return path.read_text()
    except OSError as exc:
        raise RigError(f"{path}: cannot be read ({exc.strerror})") from exc


def _yaml(path: Path, text: str) -> Any:
    try:
        return yaml.safe_load(text)
    except yaml.YAMLError as exc:
        raise RigError(f"{path}: not valid YAML ({exc})") from exc


def _floats(value: Any, count: int | None, label: str) -> list[float]:
    try:
        values = [float(v) for v in value]
    except (TypeError, ValueError):
        raise RigError(f"{label}: expected a list of numbers, got {value!r}") from None
    if count is not None and len(values) != count:
        raise RigError(f"{label}: expected {count} numbers, got {len(values)}")
    if not all(math.isfinite(v) for v in values):
        raise RigError(f"{label}: contains NaN or infinity")
    return values


def _matrix(value: Any, shape: tuple[int, int], label: str) -> np.ndarray:
    flat = _floats(np.asarray(value, dtype=object).ravel() if value is not None else None, shape[0] * shape[1], label)
    return np.asarray(flat, dtype=np.float64).reshape(shape)


def _int(data: dict[str, Any], key: str, label: str) -> int:
    value = data.get(key)
    if not isinstance(value, int) or value <= 0:
        raise RigError(f"{label} ({key}): expected a positive integer, got {value!r}")
    return value
