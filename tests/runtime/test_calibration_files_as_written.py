"""Calibration files as real tools write them, beyond the plain cases: OpenVINS's camchains with OpenCV's YAML
header, Kalibr's IMU-camera camchains, several camchains in one import, older ROS files, OpenCV XML, OCam fits
that fail or miss, fields of view within each model's domain, and files that are no calibration at all."""

from __future__ import annotations

import math
import time
import tracemalloc
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from calibration_writers import (
    KALIBR_CAMERAS,
    OPENVINS_EUROC,
    extrinsics_json,
    kalibr_camchain,
    opencv_storage,
    ros_camera_info,
)

from fisheye_infer.cameras.calibration_files import detect_format, read_calibration
from fisheye_infer.cameras.camera_models import DistortedPinhole, DoubleSphere, KannalaBrandt
from fisheye_infer.cameras.field_of_view import domain_fov, reported_fov
from fisheye_infer.cameras.ocam_fit import fit_rig_ocam
from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.cli import main
from fisheye_infer.errors import RigError

NAMES = list(KALIBR_CAMERAS)


def _camchain_text(tmp_path: Path) -> str:
    """The text of ``kalibr_camchain``'s camchain of the four wide-angle cameras."""
    path = tmp_path / "whole.yaml"
    kalibr_camchain(path)
    return path.read_text()


def _close(a: np.ndarray, b: np.ndarray, atol: float = 1e-9) -> bool:
    return bool(np.abs(np.asarray(a) - np.asarray(b)).max() < atol)


def test_an_openvins_camchain_with_opencvs_yaml_header_is_a_kalibr_camchain(tmp_path: Path) -> None:
    """OpenVINS ships EuRoC's camchain with ``%YAML:1.0`` and ``T_imu_cam``: it reads as Kalibr (OpenCV's reader
    found no camera_matrix in it), each camera placed through the IMU."""
    path = tmp_path / "kalibr_imucam_chain.yaml"
    path.write_text(OPENVINS_EUROC)
    assert detect_format(path) == "kalibr"
    cam0, cam1 = read_calibration(path)
    assert isinstance(cam0.model, DistortedPinhole) and cam0.model.distortion == (-0.28340811, 0.07395907, 0.00019359,
                                                                                 1.76187114e-05)  # fmt: skip
    assert (cam1.model.fx, cam1.model.cx, cam1.model.width) == (457.587, 379.999, 752)
    imu_cam = [np.array(yaml.safe_load(OPENVINS_EUROC.replace("%YAML:1.0", ""))[k]["T_imu_cam"]) for k in ("cam0", "cam1")]
    assert cam0.cam2first is not None and _close(cam0.cam2first, np.eye(4))
    assert cam1.cam2first is not None and _close(cam1.cam2first, np.linalg.inv(imu_cam[0]) @ imu_cam[1])
    assert abs(np.linalg.norm(cam1.cam2first[:3, 3]) - 0.110) < 1e-3  # EuRoC's stereo baseline, 11 cm


def test_a_file_storage_opencv_cannot_read_is_refused_naming_the_file(tmp_path: Path) -> None:
    """OpenCV raises ``cv2.error`` on a cut-off file and ``SystemError`` on a binary one: both are refusals."""
    whole = opencv_storage(tmp_path / "whole.yml", [0.02, -0.004, 0.001, -0.0002], fisheye=1).read_text()
    cut = tmp_path / "cut.yml"
    cut.write_text(whole[: whole.index("data:") + 12])
    with pytest.raises(RigError, match=r"cut\.yml: not an OpenCV FileStorage file OpenCV can read"):
        read_calibration(cut)
    binary = tmp_path / "binary.yml"
    binary.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(RigError, match=r"binary\.yml: not a calibration file \(byte 0x80 at offset 128"):
        read_calibration(binary, "opencv")


def test_a_camchain_with_imu_poses_alone_is_placed_through_the_imu(tmp_path: Path) -> None:
    camchain = tmp_path / "camchain-imucam.yaml"
    lidar2cam = kalibr_camchain(camchain, poses="imu")
    assert "T_cn_cnm1" not in camchain.read_text() and "T_cam_imu" in camchain.read_text()
    anchor = extrinsics_json(tmp_path / "lidar2cam.json", {NAMES[2]: lidar2cam[NAMES[2]]})
    rig = Rig.from_calibration([camchain], anchor, names=NAMES)
    for cam in rig.cameras:
        assert _close(cam.matrix, np.linalg.inv(lidar2cam[cam.name]))


def test_chain_and_imu_poses_that_disagree_are_refused_unless_told_which_to_trust(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    camchain = tmp_path / "camchain-imucam.yaml"
    lidar2cam = kalibr_camchain(camchain, poses="both")
    anchor = extrinsics_json(tmp_path / "lidar2cam.json", {NAMES[0]: lidar2cam[NAMES[0]]})
    assert len(Rig.from_calibration([camchain], anchor, names=NAMES)) == 4  # the two agree
    doc = yaml.safe_load(camchain.read_text())
    moved = np.array(doc["cam2"]["T_cam_imu"])
    moved[0, 3] += 0.005  # cam2's IMU pose 5 mm off its chain
    doc["cam2"]["T_cam_imu"] = moved.tolist()
    camchain.write_text(yaml.dump(doc, default_flow_style=None))
    with pytest.raises(RigError, match=r"camera 'cam2': T_cn_cnm1 and T_cam_imu place it 5\.0 mm and 0\.00 degrees "
                                       r"apart \(tolerance 1\.0 mm, 0\.06 degrees\); say which to trust"):  # fmt: skip
        Rig.from_calibration([camchain], anchor, names=NAMES)
    by_chain = Rig.from_calibration([camchain], anchor, names=NAMES, trust_chain="cn_cnm1")
    assert _close(by_chain.camera(NAMES[2]).matrix, np.linalg.inv(lidar2cam[NAMES[2]]))
    by_imu = Rig.from_calibration([camchain], anchor, names=NAMES, trust_chain="imu")
    cam2_to_cam0 = np.array(doc["cam0"]["T_cam_imu"]) @ np.linalg.inv(moved)  # inv(T_c2_c0) through the IMU
    assert _close(by_imu.camera(NAMES[2]).matrix, np.linalg.inv(lidar2cam[NAMES[0]]) @ cam2_to_cam0)
    assert abs(np.linalg.norm(by_imu.camera(NAMES[2]).position - by_chain.camera(NAMES[2]).position) - 0.005) < 1e-9
    out = tmp_path / "rig.yaml"
    command = ["rig", "import", str(camchain), "--extrinsics", str(anchor), "--names", ",".join(NAMES), "--out", str(out)]
    assert main(command) == 1 and "--trust-chain cn_cnm1 or imu" in capsys.readouterr().err and not out.exists()
    assert main([*command, "--trust-chain", "imu"]) == 0 and Rig.load(out).hash == by_imu.hash
    chain_only = tmp_path / "camchain.yaml"
    kalibr_camchain(chain_only)
    with pytest.raises(RigError, match="trust_chain 'imu', but not every camera has T_cam_imu"):
        read_calibration(chain_only, trust_chain="imu")


def test_a_camchain_with_neither_chain_nor_imu_poses_says_what_it_needs(tmp_path: Path) -> None:
    doc = yaml.safe_load(_camchain_text(tmp_path))
    del doc["cam1"]["T_cn_cnm1"]
    path = tmp_path / "broken.yaml"
    path.write_text(yaml.dump(doc))
    with pytest.raises(RigError, match=r"camera 'cam1': expected T_cn_cnm1 \(the chain\), or T_cam_imu on every"):
        read_calibration(path)


def test_several_camchains_are_each_placed_from_their_own_anchor(tmp_path: Path) -> None:
    """Two camchains (front and left, right and rear), each with its own cam0: each is placed from the camera of
    its own that the extrinsics give, and every camera the extrinsics give is honoured."""
    rig = default_rig()
    lidar2cam = dict(zip(rig.names, rig.lidar2cam(), strict=True))
    first, second = tmp_path / "front-left.yaml", tmp_path / "right-rear.yaml"
    kalibr_camchain(first, cameras={n: KALIBR_CAMERAS[n] for n in NAMES[:2]})
    kalibr_camchain(second, cameras={n: KALIBR_CAMERAS[n] for n in NAMES[2:]})
    anchors = extrinsics_json(tmp_path / "anchors.json", {n: lidar2cam[n] for n in (NAMES[1], NAMES[3])})
    imported = Rig.from_calibration([first, second], anchors, names=NAMES)
    for cam in imported.cameras:
        assert _close(cam.matrix, np.linalg.inv(lidar2cam[cam.name]))
    every = extrinsics_json(tmp_path / "every.json", lidar2cam)
    assert Rig.from_calibration([first, second], every, names=NAMES).hash == imported.hash
    moved = dict(lidar2cam, **{NAMES[3]: lidar2cam[NAMES[3]].copy()})
    moved[NAMES[3]][1, 3] += 0.02
    wrong = extrinsics_json(tmp_path / "wrong.json", moved)
    with pytest.raises(RigError, match=rf"camera '{NAMES[3]}': the extrinsics in .*wrong.json and the camchain "
                                       rf".*right-rear.yaml disagree by 20.0 mm"):  # fmt: skip
        Rig.from_calibration([first, second], wrong, names=NAMES)
    one = extrinsics_json(tmp_path / "one.json", {NAMES[0]: lidar2cam[NAMES[0]]})
    with pytest.raises(RigError, match=r"none of the chained cameras of .*right-rear.yaml \(fisheye_camera_right, "):
        Rig.from_calibration([first, second], one, names=NAMES)
    with pytest.raises(RigError, match=r"camera 'cam0': named twice \(.*front-left.yaml and .*right-rear.yaml\)"):
        Rig.from_calibration([first, second], every)


def test_an_older_ros_camera_info_without_distortion_model_is_plumb_bob(tmp_path: Path) -> None:
    d = [-0.28, 0.07, 1e-4, -2e-4, 0.01]
    path = ros_camera_info(tmp_path / "front.yaml", None, d)
    assert "distortion_model" not in path.read_text() and detect_format(path) == "ros"
    (cam,) = read_calibration(path)
    rays = np.array([[0.1, -0.2, 1.0], [0.4, 0.3, 1.0], [-0.5, 0.1, 1.0]])
    k = np.array([[450.0, 0, 320.0], [0, 452.0, 240.0], [0, 0, 1]])
    ref, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, np.array(d))
    assert isinstance(cam.model, DistortedPinhole) and _close(cam.model.project(rays)[0], ref.reshape(-1, 2))
    with pytest.raises(RigError, match="plumb_bob takes 5 coefficients, got 8"):
        read_calibration(ros_camera_info(tmp_path / "eight.yaml", None, [0.1] * 8))


def test_an_opencv_xml_file_is_recognised(tmp_path: Path) -> None:
    path = opencv_storage(tmp_path / "front.xml", [0.02, -0.004, 0.001, -0.0002], fisheye=1)
    assert path.read_text().startswith("<?xml") and detect_format(path) == "opencv"
    (cam,) = read_calibration(path)
    assert isinstance(cam.model, KannalaBrandt) and cam.model.k == (0.02, -0.004, 0.001, -0.0002)


def _omni_camchain(path: Path, xi: float, coeffs: list[float]) -> Path:
    cameras = {"front": ("omni", [xi, 620.0, 621.0, 399.0, 400.0], "radtan", coeffs)}
    kalibr_camchain(path, cameras=cameras)
    return path


def test_an_ocam_fit_that_fails_or_misses_is_refused_unless_forced(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A Mei lens whose undistortion diverges inside its field of view gives no finite fit; one with tangential
    distortion (not radially symmetric) misses by 12 px. Neither is written unless forced."""
    lidar2cam = {"fisheye_camera_front": default_rig().lidar2cam()[0]}
    extrinsics = extrinsics_json(tmp_path / "lidar2cam.json", lidar2cam)
    failing = _omni_camchain(tmp_path / "failing.yaml", 1.6622715, [-0.10298044, -0.1043001, 0.02684171, 0.03586719])
    out = tmp_path / "rig.yaml"
    base = ["rig", "import", "--names", "fisheye_camera_front", "--extrinsics", str(extrinsics), "--ocam"]
    assert main([*base, str(failing), "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "camera 'fisheye_camera_front': the OCam fit of its Omnidirectional lens failed" in err and not out.exists()
    rig = Rig.from_calibration([failing], extrinsics, names=["fisheye_camera_front"])
    with pytest.raises(RigError, match="lens failed"):
        fit_rig_ocam(rig, force=True)
    missing = _omni_camchain(tmp_path / "missing.yaml", 1.6, [-0.1, 0.02, 0.01, 0.0])
    assert main([*base, str(missing), "--out", str(out)]) == 1
    assert "max reprojection error above the 1 px bound (camera 'fisheye_camera_front' 12.4 px)" in capsys.readouterr().err
    assert not out.exists()
    assert main([*base, str(missing), "--force-fit", "--out", str(out)]) == 0
    assert "12.408 px (above the 1 px bound: written because of --force-fit)" in capsys.readouterr().out
    assert out.exists() and Rig.load(out).cameras[0].model.type == "ocam"
    assert main(["rig", "import", str(missing), "--names", "fisheye_camera_front", "--extrinsics", str(extrinsics),
                 "--force-fit", "--out", str(out)]) == 1  # fmt: skip
    assert "--force-fit: applies to --ocam fits" in capsys.readouterr().err


def test_a_reported_field_of_view_stays_within_what_the_model_projects(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A double sphere lens whose image border unprojects to rays beyond its domain (z > -w2 |p|): the imported
    fov stops at the domain (261.0 degrees before, 260.4 the most it projects); a rig file that states more is
    shown with what the model projects."""
    camchain = tmp_path / "camchain.yaml"
    kalibr_camchain(camchain, cameras={"front": ("ds", [-0.2, 0.57, 60.0, 60.0, 399.5, 400.5], "none", [])})
    (cam,) = read_calibration(camchain)
    assert isinstance(cam.model, DoubleSphere) and round(domain_fov(cam.model), 3) == 260.365
    assert 259.0 < cam.model.fov <= domain_fov(cam.model)
    edge = math.radians(cam.model.fov / 2)
    assert cam.model.project(np.array([[math.sin(edge), 0.0, math.cos(edge)]]))[1].all()  # the edge projects
    eucm = {"type": "eucm", "fx": 228.0, "fy": 229.0, "cx": 400.0, "cy": 399.0, "alpha": 0.63, "beta": 1.05}
    doc = {
        "name": "stated",
        "cameras": [
            {"name": "front", "model": {**cam.model.model_dump(), "fov": 360.0}, "cam2lidar": np.eye(4).tolist()},
            {"name": "left", "model": {**eucm, "width": 800, "height": 800, "fov": 360.0}, "cam2lidar": np.eye(4).tolist()},
        ],
    }
    path = tmp_path / "rig.yaml"
    path.write_text(yaml.safe_dump(doc))
    rig = Rig.load(path)
    for camera in rig.cameras:
        beyond = math.radians(domain_fov(camera.model) / 2) + 0.01
        assert not camera.model.project(np.array([[math.sin(beyond), 0.0, math.cos(beyond)]]))[1].any()
    assert [reported_fov(c.model) for c in rig.cameras] == [260.365, round(domain_fov(rig.cameras[1].model), 3)]
    assert main(["rig", "show", str(path)]) == 0
    rows = capsys.readouterr().out.splitlines()[2:]
    assert [row.split()[4] for row in rows] == ["260.365", f"{reported_fov(rig.cameras[1].model)}"]
    assert all(float(row.split()[4]) < 360 for row in rows)


# -- files that are no calibration ------------------------------------------------------------------


@pytest.mark.parametrize("format", [None, "kalibr", "ros", "opencv", "ocam"])
def test_a_binary_file_is_not_a_calibration_file(tmp_path: Path, format: str | None) -> None:
    path = tmp_path / "camchain.yaml"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 16)
    with pytest.raises(RigError, match=r"camchain\.yaml: not a calibration file \(byte 0x89 at offset 0"):
        read_calibration(path, format)


def test_a_yaml_alias_bomb_is_refused_at_once_in_bounded_memory(tmp_path: Path) -> None:
    """Nine levels of nine aliases in a camchain's distortion_coeffs would expand to 387 million numbers."""
    lines = ["a0: &a0 [0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1, 0.1]"]
    lines += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 9)}]" for i in range(1, 9)]
    chain = ("cam0:\n  camera_model: pinhole\n  intrinsics: [400.0, 400.0, 320.0, 240.0]\n  distortion_model: radtan\n"
             "  distortion_coeffs: *a8\n  resolution: [640, 480]\n")  # fmt: skip
    path = tmp_path / "camchain.yaml"
    path.write_text("\n".join(lines) + "\n" + chain)
    tracemalloc.start()
    started = time.perf_counter()
    try:
        for format in (None, "kalibr"):
            with pytest.raises(RigError, match=r"camchain\.yaml: YAML anchors and aliases \(&name, \*name\) are refused "
                                               r"\(line 1, column 5\)"):  # fmt: skip
                read_calibration(path, format)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 10 * 2**20 and time.perf_counter() - started < 5


def test_values_that_are_not_finite_are_named_as_such(tmp_path: Path) -> None:
    """OpenCV writes NaN as ``.Nan``, YAML as ``.nan``: each is "not finite" in its field, not a bound it misses."""
    path = opencv_storage(tmp_path / "nan.yml", [0.02, -0.004, 0.001, -0.0002], fisheye=1)
    path.write_text(path.read_text().replace("data: [ 330.,", "data: [ .Nan,", 1))
    assert ".Nan" in path.read_text()
    with pytest.raises(RigError, match=r"camera 'nan' \(camera_matrix\): not finite \(got \[\[nan, 0\.0, 639\.5\]"):
        read_calibration(path)
    path.write_text(path.read_text().replace("image_width: 1280", "image_width: .Nan"))
    with pytest.raises(RigError, match=r"camera 'nan' \(image_width\): not finite \(got nan\)"):
        read_calibration(path)
    doc = yaml.safe_load(_camchain_text(tmp_path))
    doc["cam0"]["intrinsics"][2] = float("nan")
    kalibr = tmp_path / "nan.yaml"
    kalibr.write_text(yaml.dump(doc))
    assert ".nan" in kalibr.read_text()
    with pytest.raises(RigError, match=r"camera 'cam0' \(intrinsics\): not finite \(got \[-0\.2, 0\.57, nan, "):
        read_calibration(kalibr)


def test_yaml_nested_too_deeply_is_refused(tmp_path: Path) -> None:
    path = tmp_path / "deep.yaml"
    path.write_text("cam0: " + "[" * 100_000 + "]" * 100_000 + "\n")
    with pytest.raises(RigError, match=r"deep\.yaml: not valid YAML \(nested too deeply\)"):
        read_calibration(path)


def test_a_huge_value_is_quoted_short(tmp_path: Path) -> None:
    doc = yaml.safe_load(_camchain_text(tmp_path))
    doc["cam0"]["distortion_coeffs"] = ["x" * 100] * 20_000
    path = tmp_path / "huge.yaml"
    path.write_text(yaml.dump(doc))
    with pytest.raises(RigError, match=r"\(distortion_coeffs\): expected a list of numbers") as refused:
        read_calibration(path)
    assert len(str(refused.value)) < 500
