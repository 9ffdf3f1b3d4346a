"""Kalibr camchains: each camera's model, and the cameras' poses relative to the first.

A camchain (``cam0``, ``cam1``, ... with ``camera_model``, ``intrinsics``, ``distortion_model``,
``distortion_coeffs``, ``resolution``) places its cameras in one of two ways, or both:

- the chain, ``T_cn_cnm1`` from ``cam1`` on (camera n-1 to camera n), as ``kalibr_calibrate_cameras``
  writes it;
- the IMU, ``T_cam_imu`` on every camera (IMU to camera), as ``kalibr_calibrate_imu_camera`` writes it,
  or its inverse ``T_imu_cam``, as OpenVINS ships its camchains. Camera n's pose in ``cam0``'s frame is
  then ``inv(T_cn_c0)`` with ``T_cn_c0 = T_cn_imu inv(T_c0_imu)``.

Where a file carries both, they must agree (``POSE_TOLERANCE_MM``, ``POSE_TOLERANCE_DEG``) unless
``trust_chain`` names the one to use: ``"cn_cnm1"`` or ``"imu"``. Models: ``pinhole`` with ``radtan``,
``equidistant`` or ``none``; ``omni`` with ``radtan`` or ``none``; ``ds`` and ``eucm`` with ``none``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Final, Literal

import numpy as np

from fisheye_infer.cameras.calibration_values import (
    POSE_TOLERANCE_DEG,
    POSE_TOLERANCE_MM,
    CalibratedCamera,
    build,
    floats,
    matrix,
    pose_difference,
    wide,
)
from fisheye_infer.cameras.camera_models import (
    DistortedPinhole,
    DoubleSphere,
    ExtendedUnified,
    KannalaBrandt,
    Omnidirectional,
    Pinhole,
)
from fisheye_infer.cameras.text_input import short
from fisheye_infer.errors import RigError

__all__ = ["TRUST_CHAIN", "TrustChain", "is_camchain", "camchain_cameras"]

#: Which placement of a camchain to use where it carries both and they disagree.
TRUST_CHAIN: Final = ("cn_cnm1", "imu")
TrustChain = Literal["cn_cnm1", "imu"]

_MODELS = {
    ("pinhole", "radtan"): "distorted_pinhole",
    ("pinhole", "equidistant"): "kannala_brandt",
    ("pinhole", "none"): "pinhole",
    ("omni", "radtan"): "omnidirectional",
    ("omni", "none"): "omnidirectional",
    ("ds", "none"): "double_sphere",
    ("eucm", "none"): "eucm",
}
_INTRINSICS = {"pinhole": 4, "omni": 5, "ds": 6, "eucm": 6}


def _camera_keys(data: Any) -> list[str]:
    if not isinstance(data, dict):
        return []
    return [k for k, v in data.items() if isinstance(v, dict) and "camera_model" in v]


def is_camchain(data: Any) -> bool:
    """Whether a parsed YAML document is a Kalibr camchain (a ``camN`` entry with ``camera_model``)."""
    return bool(_camera_keys(data))


def camchain_cameras(path: Path, data: Any, trust_chain: TrustChain | None = None) -> list[CalibratedCamera]:
    """The cameras of a parsed camchain, in file order, each with its pose in the first camera's frame."""
    if trust_chain is not None and trust_chain not in TRUST_CHAIN:
        raise RigError(f"trust_chain: expected one of {', '.join(TRUST_CHAIN)}, got {short(trust_chain)}")
    keys = _camera_keys(data)
    if not keys:
        raise RigError(f"{path}: no camera of a Kalibr camchain (cam0, cam1, ... with camera_model)")
    labels = [f"{path}: camera '{key}'" for key in keys]
    models = [_model(data[key], label) for key, label in zip(keys, labels)]
    poses = _poses(path, [data[key] for key in keys], labels, trust_chain)
    return [CalibratedCamera(str(key), model, pose) for key, model, pose in zip(keys, models, poses)]


def _poses(path: Path, entries: list[dict[str, Any]], labels: list[str], trust: TrustChain | None) -> list[np.ndarray]:
    """Each camera's pose in the first camera's frame, from the chain, the IMU or both."""
    chain = _from_chain(entries, labels)
    imu = _from_imu(entries, labels)
    if len(entries) == 1:
        return [np.eye(4)]
    if trust == "cn_cnm1" and chain is None:
        raise RigError(f"{path}: trust_chain 'cn_cnm1', but not every camera from cam1 on has T_cn_cnm1")
    if trust == "imu" and imu is None:
        raise RigError(f"{path}: trust_chain 'imu', but not every camera has T_cam_imu (or T_imu_cam)")
    if chain is not None and imu is not None and trust is None:
        for pose_chain, pose_imu, label in zip(chain, imu, labels):
            mm, deg = pose_difference(pose_chain, pose_imu)
            if mm > POSE_TOLERANCE_MM or deg > POSE_TOLERANCE_DEG:
                raise RigError(
                    f"{label}: T_cn_cnm1 and T_cam_imu place it {mm:.1f} mm and {deg:.2f} degrees apart "
                    f"(tolerance {POSE_TOLERANCE_MM} mm, {POSE_TOLERANCE_DEG} degrees); say which to trust "
                    "(--trust-chain cn_cnm1 or imu; trust_chain= in Python)"
                )
    chosen = imu if chain is None or trust == "imu" else chain
    if chosen is None:
        missing = next(label for entry, label in zip(entries[1:], labels[1:]) if "T_cn_cnm1" not in entry)
        raise RigError(f"{missing}: expected T_cn_cnm1 (the chain), or T_cam_imu on every camera (the IMU)")
    return chosen


def _from_chain(entries: list[dict[str, Any]], labels: list[str]) -> list[np.ndarray] | None:
    """Poses chained through ``T_cn_cnm1``; None where a camera lacks it."""
    if any("T_cn_cnm1" not in entry for entry in entries[1:]):
        return None
    poses = [np.eye(4)]
    for entry, label in zip(entries[1:], labels[1:]):
        step = _rigid(entry["T_cn_cnm1"], f"{label} (T_cn_cnm1)")
        poses.append(poses[-1] @ np.linalg.inv(step))  # camera n to 0 = (n-1 to 0) (n to n-1)
    return poses


def _from_imu(entries: list[dict[str, Any]], labels: list[str]) -> list[np.ndarray] | None:
    """Poses from each camera's ``T_cam_imu`` (or ``T_imu_cam``); None where a camera has neither."""
    cam_imu = []
    for entry, label in zip(entries, labels):
        if "T_cam_imu" in entry:
            cam_imu.append(_rigid(entry["T_cam_imu"], f"{label} (T_cam_imu)"))
        elif "T_imu_cam" in entry:
            cam_imu.append(np.linalg.inv(_rigid(entry["T_imu_cam"], f"{label} (T_imu_cam)")))
        else:
            return None
    return [cam_imu[0] @ np.linalg.inv(m) for m in cam_imu]  # inv(T_cn_c0), T_cn_c0 = T_cn_imu inv(T_c0_imu)


def _rigid(value: Any, label: str) -> np.ndarray:
    m = matrix(value, (4, 4), label)
    rot = m[:3, :3]
    if not np.allclose(m[3], (0, 0, 0, 1), atol=1e-9) or np.abs(rot.T @ rot - np.eye(3)).max() > 1e-4:
        raise RigError(f"{label}: expected a rigid transform (rotation and translation, last row 0 0 0 1)")
    return m


def _model(entry: dict[str, Any], label: str) -> Any:
    camera, distortion = str(entry.get("camera_model")), str(entry.get("distortion_model", "none"))
    kind = _MODELS.get((camera, distortion))
    if kind is None:
        supported = ", ".join(f"{c}-{d}" for c, d in _MODELS)
        raise RigError(
            f"{label}: camera_model {short(entry.get('camera_model'))} with distortion_model {short(distortion)} "
            f"cannot be represented (supported: {supported})"
        )
    intrinsics = floats(entry.get("intrinsics"), _INTRINSICS[camera], f"{label} (intrinsics)")
    coeffs = floats(entry.get("distortion_coeffs", []), None, f"{label} (distortion_coeffs)")
    resolution = floats(entry.get("resolution"), 2, f"{label} (resolution)")
    size = {"width": int(resolution[0]), "height": int(resolution[1])}
    if kind in ("distorted_pinhole", "kannala_brandt", "omnidirectional") and distortion != "none" and len(coeffs) != 4:
        raise RigError(f"{label} (distortion_coeffs): {distortion} takes 4 coefficients, got {len(coeffs)}")
    if camera == "pinhole":
        fx, fy, cx, cy = intrinsics
        if kind == "pinhole":
            return build(Pinhole, label, fx=fx, fy=fy, cx=cx, cy=cy, **size)
        if kind == "distorted_pinhole":
            return build(DistortedPinhole, label, fx=fx, fy=fy, cx=cx, cy=cy, distortion=tuple(coeffs), **size)
        return wide(KannalaBrandt, label, fx=fx, fy=fy, cx=cx, cy=cy, k=tuple(coeffs), **size)
    if camera == "omni":
        xi, fx, fy, cx, cy = intrinsics
        d = tuple(coeffs) if distortion == "radtan" else (0.0, 0.0, 0.0, 0.0)
        return wide(Omnidirectional, label, fx=fx, fy=fy, cx=cx, cy=cy, xi=xi, distortion=d, **size)
    if camera == "ds":
        xi, alpha, fx, fy, cx, cy = intrinsics
        return wide(DoubleSphere, label, fx=fx, fy=fy, cx=cx, cy=cy, xi=xi, alpha=alpha, **size)
    alpha, beta, fx, fy, cx, cy = intrinsics
    return wide(ExtendedUnified, label, fx=fx, fy=fy, cx=cx, cy=cy, alpha=alpha, beta=beta, **size)
