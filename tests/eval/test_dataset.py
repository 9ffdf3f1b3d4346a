"""The Fisheye3DOD reader on a small synthetic folder: frames, rigs, ground truth, and errors that say what is missing."""

from __future__ import annotations

import json
import shutil
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from eval_cases import SynthSet

from fisheye_infer.cameras.camera_models import Pinhole
from fisheye_infer.cameras.carla_poses import parse_sensor_metadata
from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS, Rig
from fisheye_infer.errors import FisheyeInferError
from fisheye_infer.eval.dataset import PINHOLE_CAMERAS, DatasetError, Fisheye3DOD
from fisheye_infer.eval.writer import camera_poses, format_record


def test_frames_come_in_split_order_with_tokens(synth_set: SynthSet) -> None:
    data = Fisheye3DOD(synth_set.root, "val")
    assert len(data) == 5
    assert data.tokens == sorted(f.token for f in synth_set.frames)
    frame = data[0]
    assert frame.token == f"{frame.scene}.{frame.vehicle}.{frame.frame_id}" and frame.weather == "ClearNoon"
    assert list(frame.image_paths) == list(FISHEYE3DOD_CAMERAS)


def test_limit_and_scene_filter(synth_set: SynthSet) -> None:
    scene = synth_set.frames[-1].token.split(".")[0]
    assert len(Fisheye3DOD(synth_set.root, limit=2)) == 2
    only = Fisheye3DOD(synth_set.root, scenes=[scene])
    assert len(only) == 2 and all(t.startswith(scene) for t in only.tokens)


def test_frame_rig_is_the_sensor_metadata_rig_of_that_frame(synth_set: SynthSet) -> None:
    frame = Fisheye3DOD(synth_set.root)[1]
    expected = Rig.from_sensor_metadata(
        synth_set.root / frame.scene / frame.vehicle, synth_set.root / "calib_results.txt", frame_id=frame.frame_id
    )
    assert frame.rig == expected


def test_camera_subset_and_images_load_on_demand(synth_set: SynthSet) -> None:
    frame = Fisheye3DOD(synth_set.root, cameras=["front", "rear"])[0]
    assert frame.rig.names == ["fisheye_camera_front", "fisheye_camera_rear"]
    image = frame.image("rear")
    assert image.shape == (80, 80, 3) and image.dtype == np.uint8
    with pytest.raises(DatasetError, match="camera 'fisheye_camera_left' was not loaded"):
        frame.image("left")


def test_ground_truth_matches_the_frames(synth_set: SynthSet) -> None:
    data = Fisheye3DOD(synth_set.root)
    gt = data.ground_truth()
    assert list(gt) == data.tokens
    for frame in data:
        assert gt[frame.token] == frame.gt_records()


def test_pinhole_cameras_when_asked(synth_set: SynthSet, tmp_path: Path) -> None:
    root = shutil.copytree(synth_set.root, tmp_path / "data")
    pinhole = Pinhole(fx=640.0, fy=640.0, cx=640.0, cy=360.0, width=1280, height=720)
    front = Fisheye3DOD(root)[0].rig.camera("fisheye_camera_front").matrix
    matrices = {name: front for name in PINHOLE_CAMERAS}
    rig = Rig.from_cameras({n: pinhole for n in PINHOLE_CAMERAS}, matrices, PINHOLE_CAMERAS)
    for entry in Fisheye3DOD(root).entries:
        folder = root / entry.scene / entry.vehicle
        lidar = parse_sensor_metadata((folder / "lidar" / "sensor_metadata.txt").read_text())[entry.frame_id]
        for name, pose in camera_poses(rig, lidar).items():
            (folder / name).mkdir(exist_ok=True)
            with open(folder / name / "sensor_metadata.txt", "a") as f:
                f.write(format_record("Image", entry.frame_id, pose, 0.0))
            (folder / name / f"{entry.frame_id}.png").write_bytes(
                (folder / "fisheye_camera_front" / f"{entry.frame_id}.png").read_bytes()
            )
    frame = Fisheye3DOD(root, pinhole=True)[0]
    assert list(frame.image_paths)[4:] == list(PINHOLE_CAMERAS)
    assert frame.pinhole_rig is not None and frame.pinhole_rig.names == list(PINHOLE_CAMERAS)
    np.testing.assert_allclose(frame.pinhole_rig.cam2lidar(), np.broadcast_to(front, (6, 4, 4)), atol=1e-12)


def _edit_json(path: Path, change: Callable[[object], object]) -> None:
    path.write_text(json.dumps(change(json.loads(path.read_text()))))


def _drop_frame_from(path: Path, frame_id: str) -> None:
    lines = path.read_text().splitlines(keepends=True)
    path.write_text("".join(line for line in lines if f"frame={int(frame_id)}," not in line))


BREAKS: list[tuple[str, Callable[[Path, str, str], None], dict, str]] = [
    ("no root", lambda root, seq, fid: shutil.rmtree(root), {}, r"dataset root .*: folder not found"),
    (
        "no split",
        lambda root, seq, fid: None,
        {"split": "test"},
        r"split 'test': .*test.json not found \(splits here: val\)",
    ),
    (
        "no calibration",
        lambda root, seq, fid: (root / "calib_results.txt").unlink(),
        {},
        r"calib_results.txt not found",
    ),
    (
        "broken calibration",
        lambda root, seq, fid: (root / "calib_results.txt").write_text("1 2 3\n"),
        {},
        r"expected 5 data rows",
    ),
    (
        "split not a list",
        lambda root, seq, fid: _edit_json(root / "ImageSets-2hz" / "val.json", lambda d: {"a": d}),
        {},
        r"must hold a list",
    ),
    (
        "split entry",
        lambda root, seq, fid: _edit_json(root / "ImageSets-2hz" / "val.json", lambda d: [{"scene_name": "x"}]),
        {},
        r"entry 0 must be an object",
    ),
    (
        "unknown scene filter",
        lambda root, seq, fid: None,
        {"scenes": ["nowhere"]},
        r"scenes: not in split 'val': nowhere",
    ),
    ("unknown camera", lambda root, seq, fid: None, {"cameras": ["top"]}, r"cameras: expected a non-empty subset"),
    ("negative limit", lambda root, seq, fid: None, {"limit": -1}, r"limit: expected a non-negative count"),
    ("no scene folder", lambda root, seq, fid: shutil.rmtree(root / seq), {}, r"scene .*/ego0: folder .* not found"),
    (
        "no camera folder",
        lambda root, seq, fid: shutil.rmtree(root / seq / "ego0" / "fisheye_camera_left"),
        {},
        r"camera 'fisheye_camera_left': folder .* not found",
    ),
    (
        "no lidar folder",
        lambda root, seq, fid: shutil.rmtree(root / seq / "ego0" / "lidar"),
        {},
        r"lidar: folder .* not found",
    ),
    (
        "no image",
        lambda root, seq, fid: (root / seq / "ego0" / "fisheye_camera_rear" / f"{fid}.png").unlink(),
        {},
        r"camera 'fisheye_camera_rear': image .* not found",
    ),
    (
        "no labels",
        lambda root, seq, fid: (root / seq / "ego0" / "label_3d" / f"{fid}.json").unlink(),
        {},
        r"labels .*: file not found",
    ),
    (
        "unknown class",
        lambda root, seq, fid: _edit_json(
            root / seq / "ego0" / "label_3d" / f"{fid}.json", lambda d: [{**d[0], "class": "Tram"}]
        ),
        {},
        r"object 0: 'class' 'Tram' is not one of Car",
    ),
    (
        "short box",
        lambda root, seq, fid: _edit_json(
            root / seq / "ego0" / "label_3d" / f"{fid}.json", lambda d: [{**d[0], "bounding_box": [1, 2, 3]}]
        ),
        {},
        r"object 0: 'bounding_box' must be 7 finite numbers",
    ),
    (
        "no camera pose",
        lambda root, seq, fid: _drop_frame_from(
            root / seq / "ego0" / "fisheye_camera_front" / "sensor_metadata.txt", fid
        ),
        {},
        r"camera 'fisheye_camera_front': no pose for frame",
    ),
    (
        "no lidar pose",
        lambda root, seq, fid: _drop_frame_from(root / seq / "ego0" / "lidar" / "sensor_metadata.txt", fid),
        {},
        r"no lidar pose for frame",
    ),
    (
        "pinhole not recorded",
        lambda root, seq, fid: None,
        {"pinhole": True},
        r"camera 'nu_rgb_camera_front': folder .* not found",
    ),
]


@pytest.mark.parametrize(("name", "breakage", "kwargs", "message"), BREAKS, ids=[b[0] for b in BREAKS])
def test_reader_errors_name_what_is_missing(
    synth_set: SynthSet, tmp_path: Path, name: str, breakage: Callable, kwargs: dict, message: str
) -> None:
    root = shutil.copytree(synth_set.root, tmp_path / "data")
    first = synth_set.frames[0]
    breakage(root, first.token.split(".")[0], first.frame_id)
    with pytest.raises(DatasetError, match=message) as info:
        list(Fisheye3DOD(root, **kwargs))
    assert isinstance(info.value, FisheyeInferError) and isinstance(info.value, ValueError)
