"""Rigs: the shipped default, rig files, CARLA sensor metadata, and errors that name the camera."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import yaml

from fisheye_infer.cameras.carla_poses import CarlaPose, cam2lidar_from_poses, parse_sensor_metadata
from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS, Rig, resolve_rig
from fisheye_infer.errors import RigError


def test_default_rig_positions_and_order(rig: Rig) -> None:
    assert rig.names == list(FISHEYE3DOD_CAMERAS)
    expected = {
        "front": (1.403, 0, 0.002),
        "left": (-0.797, 1.600, 0.007),
        "right": (-0.797, -1.600, 0.004),
        "rear": (-2.997, 0, 0.009),
    }
    for cam in rig.cameras:
        np.testing.assert_allclose(cam.position, expected[cam.name.removeprefix("fisheye_camera_")], atol=1e-3)
    headings = [round(np.degrees(c.heading)) % 360 for c in rig.cameras]
    assert headings == [0, 90, 270, 180]


def test_cam2lidar_inverts_lidar2cam(rig: Rig) -> None:
    np.testing.assert_allclose(rig.cam2lidar() @ rig.lidar2cam(), np.broadcast_to(np.eye(4), (4, 4, 4)), atol=1e-12)


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_rig_file_round_trip_keeps_hash(rig: Rig, tmp_path: Path, suffix: str) -> None:
    loaded = Rig.load(rig.save(tmp_path / f"rig{suffix}"))
    assert loaded == rig and loaded.hash == rig.hash


def test_hash_follows_content_not_name(rig: Rig) -> None:
    assert rig.model_copy(update={"name": "other"}).hash == rig.hash
    data = rig.model_dump(mode="json")
    data["cameras"][0]["cam2lidar"][0][3] += 0.01
    assert Rig.from_dict(data).hash != rig.hash


def test_hash_is_pinned_and_ignores_float_noise(rig: Rig) -> None:
    """The hash ties exported files to a rig, so it must not change between releases or machines;
    last-bit differences of the lidar2cam inverse and signed zeros do not count."""
    assert rig.hash == "0f687b5977c6d303"
    data = rig.model_dump(mode="json")
    m = data["cameras"][0]["cam2lidar"]
    m[0][0] *= 1 + 1e-15
    m[0][1] = -1e-17 if m[0][1] == 0 else m[0][1] * (1 + 1e-15)
    m[3][0] = -0.0
    assert Rig.from_dict(data).hash == rig.hash


def test_shipped_cameras_are_level(rig: Rig) -> None:
    """Settles the spec's open question (camera-data-metric.md §2.3) for the shipped rig: every optical
    axis is within 0.1 degree of horizontal, so the "compat" and "exact" CARLA conventions give the
    same cam2lidar for it (they differ only in the sign of relative pitch and roll)."""
    for cam in rig.cameras:
        axis = cam.matrix[:3, 2]
        assert abs(np.degrees(np.arcsin(axis[2]))) < 0.1, cam.name
        right = cam.matrix[:3, 0]
        assert abs(np.degrees(np.arcsin(right[2]))) < 0.1, cam.name


def _broken(rig: Rig, camera: int, path: list, value) -> dict:
    data = rig.model_dump(mode="json")
    node = data["cameras"][camera]
    for key in path[:-1]:
        node = node[key]
    node[path[-1]] = value
    return data


@pytest.mark.parametrize(
    ("camera", "path", "value", "message"),
    [
        (1, ["cam2lidar", 0, 0], float("nan"), r"camera 'fisheye_camera_left' \(cam2lidar\): contains NaN"),
        (2, ["cam2lidar", 0, 1], 0.5, r"camera 'fisheye_camera_right' \(cam2lidar\): rotation is not rigid"),
        (3, ["cam2lidar", 3, 0], 1.0, r"camera 'fisheye_camera_rear' \(cam2lidar\): last row"),
        (0, ["model", "width"], 0, r"camera 'fisheye_camera_front' \(model.width\)"),
        (0, ["model", "c"], float("nan"), r"camera 'fisheye_camera_front' \(model.c\): .*finite"),
        (1, ["name"], "fisheye_camera_front", r"unique; repeated: fisheye_camera_front"),
    ],
)
def test_bad_rig_names_camera_and_field(rig: Rig, camera: int, path: list, value, message: str) -> None:
    with pytest.raises(RigError, match=message):
        Rig.from_dict(_broken(rig, camera, path, value))


def test_require_names_order_and_image_size(rig: Rig) -> None:
    rig.require(FISHEYE3DOD_CAMERAS, (800, 800))
    with pytest.raises(RigError, match="camera 'fisheye_camera_front': image is 800x800, model expects 1600x1600"):
        rig.require(FISHEYE3DOD_CAMERAS, (1600, 1600))
    with pytest.raises(RigError, match="camera 'pinhole_front': missing from the rig"):
        rig.require(["pinhole_front"])
    with pytest.raises(RigError, match="camera order"):
        rig.require(list(reversed(FISHEYE3DOD_CAMERAS)))


def test_subset_keeps_the_cameras_named_in_their_order(rig: Rig, tmp_path: Path) -> None:
    front, left, right, rear = FISHEYE3DOD_CAMERAS
    pair = rig.subset([rear, front])
    assert pair.names == [rear, front] and pair.camera(front) == rig.camera(front)
    np.testing.assert_array_equal(pair.cam2lidar(), rig.cam2lidar()[[3, 0]])
    assert Rig.load(pair.save(tmp_path / "pair.json")) == pair and pair.hash != rig.hash
    with pytest.raises(RigError, match="camera 'front': not in the rig"):
        rig.subset([front, "front"])
    with pytest.raises(RigError, match=f"cameras: {left} named more than once"):
        rig.subset([left, right, left])
    with pytest.raises(RigError, match="cameras: expected at least one of"):
        rig.subset([])


def test_extrinsics_json_errors(rig: Rig, tmp_path: Path, data_dir: Path) -> None:
    calib = tmp_path / "calib_results.txt"
    calib.write_text(rig.shared_model().to_text())
    bad = tmp_path / "lidar2cam.json"
    bad.write_text(json.dumps({"cameras": {"front": [[1, 0, 0], [0, 1, 0]]}}))
    with pytest.raises(RigError, match=r"camera 'front' \(lidar2cam in .*\): expected a finite 4x4 matrix"):
        Rig.from_ocam_extrinsics(calib, bad)
    bad.write_text("{not json")
    with pytest.raises(RigError, match="cannot be read as JSON"):
        Rig.from_ocam_extrinsics(calib, bad)
    (tmp_path / "broken.txt").write_text("# nothing\n")
    with pytest.raises(RigError, match="expected 5 data rows"):
        Rig.from_ocam_extrinsics(tmp_path / "broken.txt", bad)


def test_resolve_rig_accepts_folder_file_and_default(rig: Rig, tmp_path: Path) -> None:
    assert resolve_rig(None) == rig and resolve_rig("default") == rig
    (tmp_path / "calib_results.txt").write_text(rig.shared_model().to_text())
    doc = {"cameras": {c.name: np.linalg.inv(c.matrix).tolist() for c in rig.cameras}}
    (tmp_path / "lidar2cam.json").write_text(json.dumps(doc))
    from_folder = resolve_rig(tmp_path)
    assert from_folder.names == rig.names and from_folder.shared_model() == rig.shared_model()
    np.testing.assert_allclose(from_folder.cam2lidar(), rig.cam2lidar(), atol=1e-12)
    with pytest.raises(RigError, match="no such file or folder"):
        resolve_rig(tmp_path / "missing.yaml")


def test_unsupported_schema_version(rig: Rig, tmp_path: Path) -> None:
    data = rig.model_dump(mode="json")
    data["schema_version"] = 99
    path = tmp_path / "rig.json"
    path.write_text(json.dumps(data))
    with pytest.raises(RigError, match="schema_version 99 is not supported"):
        Rig.load(path)


# -- CARLA sensor metadata (spec camera-data-metric.md §2) ----------------------------------

LIDAR = "Lidar(frame=26981, timestamp=1.0, number_of_points=100) frame=26981, Transform(Location(x=0.000000, y=0.000000, z=2.400000), Rotation(pitch=0.000000, yaw=0.000000, roll=0.000000))"


def _camera_record(frame: int, x: float, y: float, z: float, pitch: float, yaw: float, roll: float) -> str:
    return (
        f"Image(frame={frame}, timestamp=1.0, width=800, height=800, fov=220) frame={frame}, "
        f"Transform(Location(x={x:.6f}, y={y:.6f}, z={z:.6f}), Rotation(pitch={pitch:.6f}, yaw={yaw:.6f}, roll={roll:.6f}))"
    )


def test_worked_example_left_camera() -> None:
    """Spec §2.5: a camera 1 m to the left, facing left."""
    cam = parse_sensor_metadata(_camera_record(26981, 0, -1, 1, 0, -90, 0))["00026981"]
    lidar = parse_sensor_metadata(LIDAR)["00026981"]
    expected = [[1, 0, 0, 0], [0, 0, 1, 1], [0, -1, 0, -1.4], [0, 0, 0, 1]]
    np.testing.assert_allclose(cam2lidar_from_poses(cam, lidar), expected, atol=1e-12)


def test_worked_example_front_camera() -> None:
    cam = CarlaPose(1.5, 0.0, 1.0, 0.0, 0.0, 0.0)
    lidar = CarlaPose(0.0, 0.0, 2.4, 0.0, 0.0, 0.0)
    m = cam2lidar_from_poses(cam, lidar)
    np.testing.assert_allclose(m[:3, :3], [[0, 0, 1], [-1, 0, 0], [0, -1, 0]], atol=1e-12)
    np.testing.assert_allclose(m[:3, 3], [1.5, 0, -1.4], atol=1e-12)


def test_compat_flips_relative_pitch_exact_does_not() -> None:
    """A camera pitched down 20 degrees: exact looks down (-z), compat (as trained) looks up."""
    lidar = CarlaPose(0.0, 0.0, 2.0, 0.0, 0.0, 0.0)
    cam = CarlaPose(1.0, 0.0, 1.0, -20.0, 0.0, 0.0)
    assert cam2lidar_from_poses(cam, lidar, "exact")[2, 2] < -0.3
    assert cam2lidar_from_poses(cam, lidar, "compat")[2, 2] > 0.3
    level = CarlaPose(1.0, 0.0, 1.0, 0.0, 30.0, 0.0)
    np.testing.assert_allclose(
        cam2lidar_from_poses(level, lidar, "exact"), cam2lidar_from_poses(level, lidar, "compat"), atol=1e-12
    )


def test_rig_from_sensor_metadata(tmp_path: Path, rig: Rig) -> None:
    vehicle = tmp_path / "train-Town01_Opt-ClearNoon-2024_09_23_11_44_45" / "ego0"
    poses = {
        "fisheye_camera_front": (1.4, 0, 2.4, 0),
        "fisheye_camera_left": (-0.8, -1.6, 2.4, -90),
        "fisheye_camera_right": (-0.8, 1.6, 2.4, 90),
        "fisheye_camera_rear": (-3.0, 0, 2.4, 180),
    }
    for name, (x, y, z, yaw) in poses.items():
        (vehicle / name).mkdir(parents=True)
        (vehicle / name / "sensor_metadata.txt").write_text(
            "\n".join(_camera_record(f, x, y, z, 0, yaw, 0) for f in (26981, 26991)) + "\n"
        )
    (vehicle / "lidar").mkdir()
    (vehicle / "lidar" / "sensor_metadata.txt").write_text(LIDAR.replace("z=2.400000", "z=2.400000") + "\n")
    calib = tmp_path / "calib_results.txt"
    calib.write_text(rig.shared_model().to_text())
    built = Rig.from_sensor_metadata(vehicle, calib)
    assert built.names == list(FISHEYE3DOD_CAMERAS)
    np.testing.assert_allclose(built.camera("fisheye_camera_left").position, (-0.8, 1.6, 0.0), atol=1e-9)
    headings = [round(np.degrees(c.heading)) % 360 for c in built.cameras]
    assert headings == [0, 90, 270, 180]
    with pytest.raises(RigError, match="frame 00026991 missing from lidar"):
        Rig.from_sensor_metadata(vehicle, calib, frame_id="26991")
    (vehicle / "fisheye_camera_rear" / "sensor_metadata.txt").write_text("no records here\n")
    with pytest.raises(RigError, match="fisheye_camera_rear/sensor_metadata.txt: no 'frame=..."):
        Rig.from_sensor_metadata(vehicle, calib)


def test_rig_files_refuse_binary_aliases_and_name_what_is_not_finite(rig: Rig, tmp_path: Path) -> None:
    """A binary file is "not a rig file" (or OCam file), YAML aliases are refused, NaN (JSON's ``NaN``, YAML's
    ``.nan``) is "not finite" in its camera and field, and an extrinsics value of 100,000 characters is quoted
    short."""
    binary = tmp_path / "rig.json"
    binary.write_bytes(b"\xff\xfe" + "{}".encode("utf-16-le"))
    with pytest.raises(RigError, match=r"rig\.json: not a rig file \(byte 0xff at offset 0 is not UTF-8 text\)"):
        Rig.load(binary)
    doc = rig.model_dump(mode="json")
    bomb = tmp_path / "rig.yaml"
    bomb.write_text("x: &x [1, 2]\ny: [*x, *x]\n" + yaml.safe_dump(doc))
    with pytest.raises(RigError, match=r"rig file .*rig\.yaml: YAML anchors and aliases .* are refused"):
        Rig.load(bomb)
    doc["cameras"][1]["model"]["center_col"] = float("nan")
    for path in (tmp_path / "nan.json", tmp_path / "nan.yaml"):
        path.write_text(yaml.safe_dump(doc) if path.suffix == ".yaml" else json.dumps(doc))
        assert ("center_col: .nan" if path.suffix == ".yaml" else '"center_col": NaN') in path.read_text()
        with pytest.raises(RigError, match=r"camera 'fisheye_camera_left' \(model\.center_col\): not finite \(got nan\)"):
            Rig.load(path)
    calib = tmp_path / "calib_results.txt"
    calib.write_text(rig.shared_model().to_text())
    lidar2cam = {n: m.tolist() for n, m in zip(rig.names, rig.lidar2cam(), strict=True)}
    extrinsics = tmp_path / "lidar2cam.json"
    extrinsics.write_text(json.dumps({"cameras": {**lidar2cam, "fisheye_camera_front": "x" * 100_000}}))
    with pytest.raises(RigError, match=r"camera 'fisheye_camera_front' \(lidar2cam in .*\): expected a finite 4x4") as e:
        Rig.from_ocam_extrinsics(calib, extrinsics)
    assert len(str(e.value)) < 400
    extrinsics.write_text(json.dumps({"cameras": lidar2cam}))
    calib.write_bytes(bytes(range(128, 256)))
    with pytest.raises(RigError, match=r"OCam file .*calib_results.txt: not an OCam calib_results.txt \(byte 0x80 at"):
        Rig.from_ocam_extrinsics(calib, extrinsics)
