"""Calibration files as Kalibr, ROS and OpenCV write them, imported into a rig: models, poses, refusals, and a
rig the fisheye detectors run on (``rig import --ocam``, then ``rebake``)."""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml
from calibration_writers import KALIBR_CAMERAS, extrinsics_json, kalibr_camchain, opencv_storage, ros_camera_info

from fisheye_infer.cameras.calibration_files import detect_format, read_calibration
from fisheye_infer.cameras.camera_models import (
    DistortedPinhole,
    DoubleSphere,
    ExtendedUnified,
    KannalaBrandt,
    OCamModel,
    Omnidirectional,
    Pinhole,
)
from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.cli import main
from fisheye_infer.errors import RigError


def _rays(max_deg: float, n: int = 300) -> np.ndarray:
    rng = np.random.default_rng(1)
    a, b = rng.uniform(0, math.radians(max_deg), n), rng.uniform(-math.pi, math.pi, n)
    return np.stack([np.sin(a) * np.cos(b), np.sin(a) * np.sin(b), np.cos(a)], axis=-1)


def test_kalibr_camchain_gives_each_model_and_the_chained_poses(tmp_path: Path) -> None:
    camchain = tmp_path / "camchain.yaml"
    lidar2cam = kalibr_camchain(camchain)
    assert detect_format(camchain) == "kalibr"
    names = list(KALIBR_CAMERAS)
    anchor = extrinsics_json(tmp_path / "lidar2cam.json", {names[0]: lidar2cam[names[0]]})
    rig = Rig.from_calibration([camchain], anchor, names=names)
    for cam in rig.cameras:
        assert np.abs(cam.matrix - np.linalg.inv(lidar2cam[cam.name])).max() < 1e-9
    models = [cam.model for cam in rig.cameras]
    assert [type(m) for m in models] == [DoubleSphere, ExtendedUnified, Omnidirectional, KannalaBrandt]
    ds, eucm, omni, kb = models
    assert (ds.xi, ds.alpha, ds.fx, ds.fy, ds.cx, ds.cy) == (-0.2, 0.57, 250.0, 251.0, 399.5, 400.5)
    assert (eucm.alpha, eucm.beta, eucm.fx) == (0.63, 1.05, 228.0)
    assert (omni.xi, omni.fx, omni.distortion) == (1.6, 620.0, (-0.1, 0.02, 0.0, 0.0))
    assert kb.k == (0.02, -0.004, 0.001, -0.0002) and (kb.fx, kb.fy) == (230.0, 231.0)
    for model in models:  # the field of view the image shows: the border's rays are its largest
        border = model.unproject(np.array([[0.0, model.height / 2], [model.width / 2, 0.0]]))
        assert 90 < model.fov < 360 and model.fov >= 2 * math.degrees(np.arccos(border[:, 2]).max()) - 1e-6


def test_a_circular_fisheye_gets_the_fov_of_its_image_circle() -> None:
    """The image circle inside the frame: the border shows no ray, the circle's edge gives the fov (to the
    pixel: the angle rises steeply at the edge, 1.8 degrees over its last pixel here)."""
    from fisheye_infer.cameras.calibration_files import image_fov

    lens = DoubleSphere(fx=100.0, fy=100.0, cx=400.0, cy=400.0, xi=0.0, alpha=0.6, width=800, height=800, fov=360.0)
    edge = 100.0 / math.sqrt(2 * 0.6 - 1)  # alpha > 0.5: the sphere's image is a disc of this radius (px)
    ray = lens.unproject(np.array([[400.0 + edge * (1 - 1e-9), 400.0]]))[0]
    assert 2 * math.degrees(math.acos(ray[2])) - 2.5 < image_fov(lens) <= 2 * math.degrees(math.acos(ray[2]))


def test_kalibr_cameras_given_twice_must_agree_with_the_chain(tmp_path: Path) -> None:
    camchain = tmp_path / "camchain.yaml"
    lidar2cam = kalibr_camchain(camchain)
    names = list(KALIBR_CAMERAS)
    both = extrinsics_json(tmp_path / "both.json", {n: lidar2cam[n] for n in names[:2]})
    assert len(Rig.from_calibration([camchain], both, names=names)) == 4
    moved = dict(lidar2cam)
    moved[names[1]] = moved[names[1]].copy()
    moved[names[1]][0, 3] += 0.01
    wrong = extrinsics_json(tmp_path / "wrong.json", {n: moved[n] for n in names[:2]})
    with pytest.raises(RigError, match=rf"camera '{names[1]}'.*disagree by 10.0 mm"):
        Rig.from_calibration([camchain], wrong, names=names)
    with pytest.raises(RigError, match="none of the chained cameras"):
        Rig.from_calibration([camchain], extrinsics_json(tmp_path / "other.json", {"cam9": np.eye(4)}))


def test_a_camera_kalibr_calibrated_otherwise_is_refused_with_the_reason(tmp_path: Path) -> None:
    doc = {"cam0": {"camera_model": "pinhole", "intrinsics": [1, 1, 0, 0], "distortion_model": "fov",
                    "distortion_coeffs": [0.9], "resolution": [640, 480]}}  # fmt: skip
    path = tmp_path / "camchain.yaml"
    path.write_text(yaml.dump(doc))
    with pytest.raises(RigError, match="camera 'cam0': camera_model 'pinhole' with distortion_model 'fov' cannot be"):
        read_calibration(path)
    doc["cam0"].update(distortion_model="radtan", distortion_coeffs=[0.1, 0.0, 0.0])
    path.write_text(yaml.dump(doc))
    with pytest.raises(RigError, match=r"\(distortion_coeffs\): radtan takes 4 coefficients, got 3"):
        read_calibration(path)


def test_ros_camera_info_models(tmp_path: Path) -> None:
    k = np.array([[450.0, 0, 320.0], [0, 452.0, 240.0], [0, 0, 1]])
    rays = _rays(35)
    for model, d in (
        ("plumb_bob", [-0.28, 0.07, 1e-4, -2e-4, 0.01]),
        ("rational_polynomial", [0.4, -0.1, 2e-4, 1e-4, 0.02, 0.7, -0.05, 0.03]),
    ):
        path = ros_camera_info(tmp_path / f"{model}.yaml", model, d)
        assert detect_format(path) == "ros"
        (cam,) = read_calibration(path)
        assert cam.name == "front" and isinstance(cam.model, DistortedPinhole) and cam.cam2first is None
        ref, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), k, np.array(d))
        assert np.abs(cam.model.project(rays)[0] - ref.reshape(-1, 2)).max() < 1e-9
    (cam,) = read_calibration(ros_camera_info(tmp_path / "equi.yaml", "equidistant", [0.02, -0.004, 0.001, -0.0002]))
    ref, _ = cv2.fisheye.projectPoints(
        rays.reshape(-1, 1, 3), np.zeros(3), np.zeros(3), k, np.array([0.02, -0.004, 0.001, -0.0002])
    )
    assert isinstance(cam.model, KannalaBrandt) and np.abs(cam.model.project(rays)[0] - ref.reshape(-1, 2)).max() < 1e-9
    (cam,) = read_calibration(ros_camera_info(tmp_path / "ideal.yaml", "plumb_bob", [0.0] * 5))
    assert isinstance(cam.model, Pinhole)
    with pytest.raises(RigError, match="'fov_model' cannot be represented"):
        read_calibration(ros_camera_info(tmp_path / "fov.yaml", "fov_model", [0.9]))
    with pytest.raises(RigError, match="plumb_bob takes 5 coefficients, got 4"):
        read_calibration(ros_camera_info(tmp_path / "short.yaml", "plumb_bob", [0.1, 0.0, 0.0, 0.0]))


def test_opencv_file_storage_fisheye_and_pinhole(tmp_path: Path) -> None:
    fisheye = opencv_storage(tmp_path / "fisheye.yml", [0.02, -0.004, 0.001, -0.0002], fisheye=1)
    assert detect_format(fisheye) == "opencv"
    (cam,) = read_calibration(fisheye)
    assert isinstance(cam.model, KannalaBrandt) and cam.model.k == (0.02, -0.004, 0.001, -0.0002)
    assert (cam.model.width, cam.model.height, cam.model.fx, cam.model.cy) == (1280, 960, 330.0, 479.5)
    (cam,) = read_calibration(opencv_storage(tmp_path / "pinhole.yml", [-0.28, 0.07, 1e-4, -2e-4, 0.01], fisheye=0))
    assert isinstance(cam.model, DistortedPinhole) and cam.model.distortion == (-0.28, 0.07, 1e-4, -2e-4, 0.01)
    with pytest.raises(RigError, match="fit both cv::fisheye"):
        read_calibration(opencv_storage(tmp_path / "ambiguous.yml", [0.1, 0.0, 0.0, 0.0], fisheye=None))


def test_a_file_of_no_known_format_says_what_it_reads(tmp_path: Path) -> None:
    path = tmp_path / "other.yaml"
    path.write_text("a: 1\n")
    with pytest.raises(
        RigError, match="Kalibr camchain, a ROS CameraInfo YAML, an OpenCV FileStorage file or an OCamCalib"
    ):
        detect_format(path)


def test_rig_import_with_ocam_gives_a_rig_the_fisheye_detectors_take(
    small_export, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A camchain of the reduced model's four cameras (160x160, each its own double sphere lens) imported with
    ``--ocam``, then ``rebake``: the file, exported for one shared lens, runs on four calibrations."""
    from fisheye_infer.runtime.artifact import read_meta
    from fisheye_infer.runtime.detector import Detector

    camchain = tmp_path / "camchain.yaml"
    lenses = {
        name: ("ds", [-0.2 + 0.01 * n, 0.57, 50.0 + n, 50.5 + n, 79.5 - n, 79.5 + 0.5 * n], "none", [])
        for n, name in enumerate(KALIBR_CAMERAS)
    }
    lidar2cam = kalibr_camchain(camchain, resolution=(160, 160), cameras=lenses)
    extrinsics = extrinsics_json(tmp_path / "lidar2cam.json", {"fisheye_camera_front": lidar2cam["fisheye_camera_front"]})
    out = tmp_path / "imported.yaml"
    command = ["rig", "import", str(camchain), "--extrinsics", str(extrinsics), "--names", ",".join(KALIBR_CAMERAS)]
    assert main([*command, "--ocam", "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    errors = [float(line.split("error ")[1].split(" px")[0]) for line in printed.splitlines() if "OCam fit" in line]
    assert len(errors) == 4 and max(errors) < 1.0 and (tmp_path / "imported.png").stat().st_size > 0
    rig = Rig.load(out)
    assert all(isinstance(cam.model, OCamModel) for cam in rig.cameras) and rig.names == list(KALIBR_CAMERAS)
    assert len({cam.model for cam in rig.cameras}) == 4
    assert main(["rig", "show", str(out)]) == 0 and "ocam" in capsys.readouterr().out
    rebaked = tmp_path / "rebaked.onnx"
    assert main(["rebake", str(small_export.onnx), "--rig", str(out), "--out", str(rebaked)]) == 0
    assert read_meta(rebaked).rig.hash == rig.hash
    frame = {name: np.zeros((160, 160, 3), np.uint8) for name in rig.names}
    assert Detector(rebaked, threads=1).detect(frame).boxes.shape[1] == 7


def test_ocamcalib_files_one_per_camera_give_each_camera_its_lens(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """Four ``calib_results.txt`` as OCamCalib writes them, one per camera folder (the shipped file with each
    camera's image centre where its own calibration put it): each camera named by its folder, with its own lens,
    and a file that is not OCam's refused with the formats named."""
    shipped = (Path(__file__).resolve().parents[2] / "fisheye_infer/data/rig-fisheye3dod/calib_results.txt").read_text()
    assert "398.967516 399.029971" in shipped  # its centre row and column
    rig = default_rig()
    files = []
    for n, name in enumerate(rig.names):
        centre = f"{398.967516 + 2 * n:.6f} {399.029971 - n:.6f}"
        path = tmp_path / name / "calib_results.txt"
        path.parent.mkdir()
        path.write_text(shipped.replace("398.967516 399.029971", centre))
        files.append(str(path))
    assert detect_format(files[0]) == "ocam"
    extrinsics = extrinsics_json(tmp_path / "lidar2cam.json", dict(zip(rig.names, rig.lidar2cam(), strict=True)))
    out = tmp_path / "rig.yaml"
    assert main(["rig", "import", *files, "--extrinsics", str(extrinsics), "--out", str(out)]) == 0
    imported = Rig.load(out)
    assert imported.names == rig.names and len({cam.model for cam in imported.cameras}) == 4
    assert imported.cameras[0].model == rig.cameras[0].model  # the shipped file unchanged is the shipped lens
    assert [cam.model.center_row for cam in imported.cameras] == pytest.approx([398.967516 + 2 * n for n in range(4)])
    np.testing.assert_allclose(imported.cam2lidar(), rig.cam2lidar(), atol=1e-12)
    capsys.readouterr()
    assert main(["rig", "show", str(out)]) == 0
    rows = capsys.readouterr().out.splitlines()[2:]
    assert [row.split()[2] for row in rows] == ["1", "2", "3", "4"]  # the lens column: four calibrations
    assert main(["rig", "show", "default"]) == 0
    assert [row.split()[2] for row in capsys.readouterr().out.splitlines()[2:]] == ["1"] * 4  # one shared
    broken = tmp_path / "broken.txt"
    broken.write_text(shipped.replace("800 800", "800"))
    with pytest.raises(RigError, match="OCam file .*broken.txt"):
        read_calibration(broken)
