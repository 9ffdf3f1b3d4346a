"""Synthetic scenes: the reader gets back exactly what was written, the pictures show the boxes, seeds repeat."""

from __future__ import annotations

import math
import re
from pathlib import Path

import cv2
import numpy as np
import pytest
from eval_cases import SynthSet

from fisheye_infer.cameras.carla_poses import CarlaPose, cam2lidar_from_poses
from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.eval.writer import camera_poses
from fisheye_infer.runtime.records import CLASSES
from fisheye_infer.scenes.render import Renderer, resized_rig, synthesize
from fisheye_infer.scenes.scene import CLASS_SIZES, Scene, random_scene


def test_reader_reads_back_the_rig_and_boxes_written(synth_set: SynthSet) -> None:
    frames = {f.token: f for f in Fisheye3DOD(synth_set.root)}
    assert set(frames) == {s.token for s in synth_set.frames}
    for written in synth_set.frames:
        read = frames[written.token]
        assert read.rig == written.rig  # bit for bit: the writer returns what the text encodes
        np.testing.assert_allclose(read.rig.cam2lidar(), synth_set.rig.cam2lidar(), atol=1e-12)
        assert read.rig.shared_model() == synth_set.rig.shared_model()
        np.testing.assert_array_equal(read.gt_boxes, written.boxes)
        np.testing.assert_array_equal(read.gt_labels, written.labels)
        assert len(written.boxes) >= 6


def test_sensor_metadata_matches_the_official_record_pattern(synth_set: SynthSet) -> None:
    # The official parser accepts digits, '-' and '.' only (no exponent) and needs a space after each comma.
    number = r"[-.\d]+"
    pattern = re.compile(
        rf"frame=(\d+), .*?Transform\(Location\(x={number},\s+y={number},\s+z={number}\),\s+Rotation\(pitch={number},\s+yaw={number},\s+roll={number}\)\)"
    )
    for path in synth_set.root.rglob("sensor_metadata.txt"):
        lines = path.read_text().splitlines()
        assert lines and all(pattern.search(line) for line in lines), path


def test_split_file_links_neighbouring_frames(synth_set: SynthSet) -> None:
    entries = Fisheye3DOD(synth_set.root).entries
    first_scene = [e for e in entries if e.scene == entries[0].scene]
    assert [e.prev_id for e in first_scene] == ["", first_scene[0].frame_id, first_scene[1].frame_id]
    assert [e.next_id for e in first_scene] == [first_scene[1].frame_id, first_scene[2].frame_id, ""]


def test_same_seed_writes_the_same_bytes(small_rig: Rig, tmp_path: Path) -> None:
    a, b, c = (
        synthesize(small_rig, tmp_path / name, frames=1, seed=seed) for name, seed in (("a", 3), ("b", 3), ("c", 4))
    )
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a").rglob("*") if p.is_file())
    assert files and all((tmp_path / "a" / f).read_bytes() == (tmp_path / "b" / f).read_bytes() for f in files)
    assert not np.array_equal(a[0].boxes, c[0].boxes)


@pytest.fixture(scope="module")
def ring_scene() -> Scene:
    """One box of every class, 9 m away, spread round the vehicle."""
    boxes = []
    for i, cls in enumerate(CLASSES):
        angle = i * math.pi / 3 + 0.3
        length, width, height = CLASS_SIZES[cls]
        boxes.append([9 * math.cos(angle), 9 * math.sin(angle), -2.0, length, width, height, angle + 0.5])
    return Scene(np.array(boxes), np.arange(len(CLASSES)), ground_z=-2.0)


def test_boxes_are_visible_where_they_project(ring_scene: Scene) -> None:
    rig = resized_rig(default_rig(), 0.25)
    renderer = Renderer()
    with_boxes = renderer.render(rig, ring_scene)
    empty = renderer.render(rig, Scene(np.zeros((0, 7)), np.zeros(0, np.int64), ring_scene.ground_z))
    seen = 0
    for cam in rig.cameras:
        centres = np.column_stack(
            [
                ring_scene.boxes[:, :2],
                ring_scene.boxes[:, 2] + ring_scene.boxes[:, 5] / 2,
                np.ones(len(ring_scene.boxes)),
            ]
        )
        in_camera = (np.linalg.inv(cam.matrix) @ centres.T).T[:, :3]
        uv, valid = cam.model.project(in_camera)
        for (u, v), ok in zip(np.round(uv).astype(int), valid):
            if ok:
                seen += 1
                assert np.abs(with_boxes[cam.name][v, u].astype(int) - empty[cam.name][v, u]).max() > 20, (
                    cam.name,
                    u,
                    v,
                )
    assert seen >= len(CLASSES)  # every box is in at least one camera
    for cam in rig.cameras:
        image = empty[cam.name]
        assert image.std() > 10 and (image[0, 0] == 0).all()  # textured, black outside the lens


def test_box_pixels_carry_the_class_colour(ring_scene: Scene) -> None:
    from fisheye_infer.scenes.scene import CLASS_COLOURS

    rig = resized_rig(default_rig(), 0.25)
    images = Renderer().render(rig, ring_scene)
    cam = rig.camera("fisheye_camera_front")
    centre = np.array(
        [*ring_scene.boxes[0, :2], ring_scene.boxes[0, 2] + ring_scene.boxes[0, 5] / 2, 1.0]
    )  # the Car, ahead-left
    uv, valid = cam.model.project((np.linalg.inv(cam.matrix) @ centre)[None, :3])
    assert valid[0]
    pixel = images[cam.name][int(round(uv[0, 1])), int(round(uv[0, 0]))].astype(float)
    colour = np.array(CLASS_COLOURS["Car"], float)
    cosine = pixel @ colour / (np.linalg.norm(pixel) * np.linalg.norm(colour))
    assert cosine > 0.99  # shaded, but the same hue


def test_full_size_frame(tmp_path: Path) -> None:
    (frame,) = synthesize(default_rig(), tmp_path, frames=1, seed=11)
    read = Fisheye3DOD(tmp_path)[0]
    for name in read.rig.names:
        image = read.image(name)
        assert image.shape == (800, 800, 3) and image.std() > 20
    np.testing.assert_array_equal(read.gt_boxes, frame.boxes)


def test_random_scene_objects_stand_apart_on_the_ground() -> None:
    scene = random_scene(np.random.default_rng(0), (20, 20), ground_z=-1.5)
    assert len(scene.boxes) == 20 and np.all(scene.boxes[:, 2] == -1.5)
    xy, radius = scene.boxes[:, :2], np.hypot(scene.boxes[:, 3], scene.boxes[:, 4]) / 2
    gaps = np.hypot(*(xy[:, None] - xy[None]).transpose(2, 0, 1)) - radius[:, None] - radius[None]
    assert gaps[~np.eye(20, dtype=bool)].min() > 0
    assert np.all(np.hypot(*xy.T) >= 4.0)


def test_resized_model_projects_to_the_scaled_pixels() -> None:
    original = default_rig().shared_model()
    small = resized_rig(default_rig(), 0.25).shared_model()
    assert (small.width, small.height) == (200, 200)
    rays = np.random.default_rng(0).normal(size=(200, 3))
    rays[:, 2] = np.abs(rays[:, 2])
    np.testing.assert_allclose(small.world2cam(rays), (original.world2cam(rays) + 0.5) * 0.25 - 0.5, atol=1e-9)
    pixels = np.array([[10.0, 20.0], [100.0, 100.0], [150.5, 30.25]])
    np.testing.assert_allclose(small.cam2world(pixels), original.cam2world((pixels + 0.5) / 0.25 - 0.5), atol=1e-12)


@pytest.mark.parametrize("convention", ["compat", "exact"])
@pytest.mark.parametrize(
    "lidar",
    [
        CarlaPose(0, 0, 2.4, 0, 0, 0),
        CarlaPose(150.0, -30.0, 2.0, 0.0, 123.0, 0.0),
        CarlaPose(10.0, 5.0, 2.0, 4.0, -60.0, -2.0),
    ],
    ids=["origin", "driving", "on a slope"],
)
def test_camera_poses_invert_the_conversion_for_tilted_cameras(convention: str, lidar: CarlaPose) -> None:
    rig = default_rig()
    tilt = np.eye(4)
    a, b = math.radians(20), math.radians(5)  # pitched down 20 degrees, rolled 5 degrees
    tilt[:3, :3] = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]]) @ np.array(
        [[math.cos(b), -math.sin(b), 0], [math.sin(b), math.cos(b), 0], [0, 0, 1]]
    )
    tilted = Rig.from_cameras(
        {c.name: c.model for c in rig.cameras}, {c.name: c.matrix @ tilt for c in rig.cameras}, rig.names
    )
    poses = camera_poses(tilted, lidar, convention)  # type: ignore[arg-type]
    for cam in tilted.cameras:
        np.testing.assert_allclose(cam2lidar_from_poses(poses[cam.name], lidar, convention), cam.matrix, atol=1e-12)  # type: ignore[arg-type]


def test_images_are_png_bgr_as_training_reads_them(synth_set: SynthSet) -> None:
    frame = Fisheye3DOD(synth_set.root)[0]
    path = frame.image_paths["fisheye_camera_front"]
    assert path.suffix == ".png" and path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    np.testing.assert_array_equal(frame.image("front"), cv2.imread(str(path), cv2.IMREAD_COLOR))


def test_writing_a_frame_again_replaces_it(small_rig: Rig, tmp_path: Path) -> None:
    synthesize(small_rig, tmp_path, frames=2, seed=5)
    (again,) = synthesize(small_rig, tmp_path, frames=1, seed=6, scene_name="synth-Town00-ClearNoon-seed5")
    metadata = (
        (tmp_path / "synth-Town00-ClearNoon-seed5" / "ego0" / "lidar" / "sensor_metadata.txt").read_text().splitlines()
    )
    assert len(metadata) == 2
    data = Fisheye3DOD(tmp_path)
    assert len(data) == 2 and data[0].rig == again.rig
    np.testing.assert_array_equal(data[0].gt_boxes, again.boxes)


def test_cameras_with_lenses_of_their_own_are_read_back_with_them(small_rig: Rig, tmp_path: Path) -> None:
    """Four calibrations, one per camera: each goes into its camera's folder, none to the root, and the reader
    gives every camera its own; a camera folder without one and no root file is refused by name."""
    from small_configs import own_lenses

    from fisheye_infer.eval.dataset import DatasetError

    rig = own_lenses(small_rig)
    root = tmp_path / "Fisheye3DOD"
    written = synthesize(rig, root, frames=2, seed=3)
    assert not (root / "calib_results.txt").exists()
    assert len(list(root.glob("*/*/fisheye_camera_*/calib_results.txt"))) == 4
    frames = list(Fisheye3DOD(root))
    assert [f.rig for f in frames] == [w.rig for w in written]
    assert [c.model for c in frames[0].rig.cameras] == [c.model for c in rig.cameras]
    next(root.glob("*/*/fisheye_camera_left/calib_results.txt")).unlink()
    with pytest.raises(DatasetError, match=r"camera 'fisheye_camera_left': calib_results.txt not found"):
        list(Fisheye3DOD(root))


def test_a_sequence_of_another_shared_lens_keeps_its_own(small_rig: Rig, tmp_path: Path) -> None:
    """The root holds the first lens written; a sequence whose cameras share another gets it in their folders, and
    a sequence written with lenses of their own is not overwritten by a shared one."""
    from small_configs import own_lenses

    from fisheye_infer.eval.dataset import DatasetError

    root = tmp_path / "Fisheye3DOD"
    other = Rig.from_dict(
        {**small_rig.model_dump(mode="json"), "cameras": [
            {**cam, "model": own_lenses(small_rig).cameras[1].model.model_dump(mode="json")}
            for cam in small_rig.model_dump(mode="json")["cameras"]
        ]}
    )  # fmt: skip
    first = synthesize(small_rig, root, frames=1, seed=1, scene_name="synth-Town00-ClearNoon-0001")
    second = synthesize(other, root, frames=1, seed=2, scene_name="synth-Town00-ClearNoon-0002")
    read = {f.token: f.rig for f in Fisheye3DOD(root)}
    assert read == {first[0].token: first[0].rig, second[0].token: second[0].rig}
    assert len(list(root.glob("synth-Town00-ClearNoon-0002/*/*/calib_results.txt"))) == 4
    synthesize(own_lenses(small_rig), root, frames=1, seed=3, scene_name="synth-Town00-ClearNoon-0003")
    with pytest.raises(DatasetError, match="already holds a different camera model"):
        synthesize(small_rig, root, frames=1, seed=3, scene_name="synth-Town00-ClearNoon-0003")


def test_lenses_of_other_models_and_sizes_are_written_as_camera_model_files(small_rig: Rig, tmp_path: Path) -> None:
    """A double sphere and an EUCM camera of their own sizes: each camera folder holds its model as JSON, the reader
    gives it back with its images at their size; a damaged model file is refused by name."""
    from fisheye_infer.cameras.camera_models import DoubleSphere, ExtendedUnified
    from fisheye_infer.eval.dataset import DatasetError
    from fisheye_infer.scenes.streams import SyntheticFrames, write_split

    models = {
        "fisheye_camera_front": DoubleSphere(
            width=96, height=96, fx=21.0, fy=21.0, cx=47.5, cy=47.5, xi=-0.17, alpha=0.59, fov=220.0
        ),
        "fisheye_camera_left": ExtendedUnified(
            width=120, height=90, fx=23.0, fy=23.0, cx=59.5, cy=44.5, alpha=0.61, beta=1.07, fov=220.0
        ),
    }
    rig = small_rig.model_copy(
        update={
            "cameras": tuple(c.model_copy(update={"model": models.get(c.name, c.model)}) for c in small_rig.cameras)
        }
    )
    root = tmp_path / "data"
    write_split(SyntheticFrames(rig, "val", 0), root, range(2))
    assert len(list(root.glob("*/*/fisheye_camera_*/camera_model.json"))) == 2
    frames = list(Fisheye3DOD(root))
    assert [c.model for c in frames[0].rig.cameras] == [c.model for c in rig.cameras]
    assert cv2.imread(str(frames[1].image_paths["fisheye_camera_left"])).shape == (90, 120, 3)
    next(root.glob("*/*/fisheye_camera_left/camera_model.json")).write_text('{"type": "eucm"}')
    with pytest.raises(DatasetError, match=r"camera 'fisheye_camera_left': .*camera_model.json is not a camera model"):
        list(Fisheye3DOD(root))
