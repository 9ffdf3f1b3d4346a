"""Calibration files written as the tools write them (Kalibr, OpenVINS, ROS ``camera_calibration_parsers``, OpenCV's
``cv::FileStorage``), for the calibration import tests."""

from __future__ import annotations

import json
from pathlib import Path

import cv2
import numpy as np
import yaml

from fisheye_infer.cameras.rig import default_rig

#: One Kalibr camera of each wide-angle model it calibrates: (camera_model, intrinsics, distortion_model, coeffs).
KALIBR_CAMERAS = {
    "fisheye_camera_front": ("ds", [-0.2, 0.57, 250.0, 251.0, 399.5, 400.5], "none", []),
    "fisheye_camera_left": ("eucm", [0.63, 1.05, 228.0, 229.0, 400.0, 399.0], "none", []),
    "fisheye_camera_right": ("omni", [1.6, 620.0, 621.0, 399.0, 400.0], "radtan", [-0.1, 0.02, 0.0, 0.0]),
    "fisheye_camera_rear": ("pinhole", [230.0, 231.0, 400.0, 400.0], "equidistant", [0.02, -0.004, 0.001, -0.0002]),
}


#: The IMU's pose in the lidar frame the Kalibr IMU-camera calibrations below are written for (lidar to IMU).
LIDAR2IMU = np.array(
    [[0.9848077530, -0.1736481777, 0.0, 0.12], [0.1736481777, 0.9848077530, 0.0, -0.03], [0, 0, 1, -0.25], [0, 0, 0, 1]]
)


def kalibr_camchain(
    path: Path,
    resolution: tuple[int, int] = (800, 800),
    cameras: dict[str, tuple] = KALIBR_CAMERAS,
    poses: str = "chain",
) -> dict[str, np.ndarray]:
    """A camchain as Kalibr writes it (``cam0``, ``cam1``, ... in ``cameras`` order, from the shipped rig's poses):
    ``poses`` "chain" gives ``T_cn_cnm1`` (``kalibr_calibrate_cameras``), "imu" ``T_cam_imu`` alone and "both"
    both (``kalibr_calibrate_imu_camera``'s camchain-imucam, with ``LIDAR2IMU``). Returns the lidar2cam of each
    camera."""
    rig = default_rig()
    lidar2cam = dict(zip(rig.names, rig.lidar2cam(), strict=True))
    chain: dict[str, dict] = {}
    previous = None
    for i, (name, (model, intrinsics, distortion, coeffs)) in enumerate(cameras.items()):
        entry: dict = {
            "camera_model": model,
            "intrinsics": intrinsics,
            "distortion_model": distortion,
            "distortion_coeffs": coeffs,
            "resolution": list(resolution),
            "rostopic": f"/{name}/image_raw",
        }
        if poses in ("imu", "both"):
            entry["T_cam_imu"] = (lidar2cam[name] @ np.linalg.inv(LIDAR2IMU)).tolist()
            entry["timeshift_cam_imu"] = 0.0021
        if previous is not None:
            if poses in ("chain", "both"):
                entry["T_cn_cnm1"] = (lidar2cam[name] @ np.linalg.inv(lidar2cam[previous])).tolist()
            entry["cam_overlaps"] = [i - 1]
        chain[f"cam{i}"] = entry
        previous = name
    path.write_text(yaml.dump(chain, default_flow_style=None))
    return lidar2cam


#: OpenVINS's ``config/euroc_mav/kalibr_imucam_chain.yaml`` (EuRoC's two cameras): OpenCV's ``%YAML:1.0``
#: header, ``T_imu_cam`` (camera to IMU) per camera, comments after values.
OPENVINS_EUROC = """%YAML:1.0

cam0:
  T_imu_cam: #rotation from camera to IMU R_CtoI, position of camera in IMU p_CinI
    - [0.0148655429818, -0.999880929698, 0.00414029679422, -0.0216401454975]
    - [0.999557249008, 0.0149672133247, 0.025715529948, -0.064676986768]
    - [-0.0257744366974, 0.00375618835797, 0.999660727178, 0.00981073058949]
    - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [1]
  camera_model: pinhole
  distortion_coeffs: [-0.28340811, 0.07395907, 0.00019359, 1.76187114e-05]
  distortion_model: radtan
  intrinsics: [458.654, 457.296, 367.215, 248.375] #fu, fv, cu, cv
  resolution: [752, 480]
  rostopic: /cam0/image_raw
cam1:
  T_imu_cam: #rotation from camera to IMU R_CtoI, position of camera in IMU p_CinI
    - [0.0125552670891, -0.999755099723, 0.0182237714554, -0.0198435579556]
    - [0.999598781151, 0.0130119051815, 0.0251588363115, 0.0453689425024]
    - [-0.0253898008918, 0.0179005838253, 0.999517347078, 0.00786212447038]
    - [0.0, 0.0, 0.0, 1.0]
  cam_overlaps: [0]
  camera_model: pinhole
  distortion_coeffs: [-0.28368365,0.07451284,-0.00010473,-3.55590700e-05]
  distortion_model: radtan
  intrinsics: [457.587, 456.134, 379.999, 255.238] #fu, fv, cu, cv
  resolution: [752, 480]
  rostopic: /cam1/image_raw
"""


def extrinsics_json(path: Path, lidar2cam: dict[str, np.ndarray]) -> Path:
    path.write_text(json.dumps({"cameras": {name: m.tolist() for name, m in lidar2cam.items()}}))
    return path


def ros_camera_info(path: Path, model: str | None, d: list[float], name: str = "front") -> Path:
    """The layout ``camera_calibration_parsers`` writes; without ``distortion_model`` where ``model`` is None, as
    its older versions wrote it."""
    k = [450.0, 0.0, 320.0, 0.0, 452.0, 240.0, 0.0, 0.0, 1.0]
    doc = {
        "image_width": 640,
        "image_height": 480,
        "camera_name": name,
        "camera_matrix": {"rows": 3, "cols": 3, "data": k},
        **({} if model is None else {"distortion_model": model}),
        "distortion_coefficients": {"rows": 1, "cols": len(d), "data": d},
        "rectification_matrix": {"rows": 3, "cols": 3, "data": [1.0, 0, 0, 0, 1.0, 0, 0, 0, 1.0]},
        "projection_matrix": {"rows": 3, "cols": 4, "data": [450.0, 0, 320.0, 0, 0, 452.0, 240.0, 0, 0, 0, 1.0, 0]},
    }
    path.write_text(yaml.safe_dump(doc, sort_keys=False))
    return path


def opencv_storage(path: Path, d: list[float], fisheye: int | None) -> Path:
    """What OpenCV's calibration sample writes (``cv::FileStorage``)."""
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", 1280)
    fs.write("image_height", 960)
    fs.write("flags", 0)
    if fisheye is not None:
        fs.write("fisheye_model", fisheye)
    fs.write("camera_matrix", np.array([[330.0, 0, 639.5], [0, 331.0, 479.5], [0, 0, 1]]))
    fs.write("distortion_coefficients", np.array(d, np.float64).reshape(-1, 1))
    fs.write("avg_reprojection_error", 0.21)
    fs.release()
    return path
