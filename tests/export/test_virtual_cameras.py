"""Virtual cameras: a robot's cameras resampled in the graph into the training cameras' images.

The front end is checked against an independent numpy + OpenCV implementation (ray through the training lens,
rotation into the robot mount, projection through the robot lens, cv2.remap) for every camera model; a file with
virtual cameras on its own training rig answers as the unchanged file; cameras are mapped by name or heading,
never by file order; each camera is fed at its own size.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from fisheye_infer import Detector
from fisheye_infer.cameras.camera_map import map_cameras, parse_camera_map
from fisheye_infer.cameras.camera_models import (
    DistortedPinhole,
    DoubleSphere,
    Equidistant,
    ExtendedUnified,
    KannalaBrandt,
    OCamModel,
    Omnidirectional,
    incidence_angle,
)
from fisheye_infer.cameras.rig import Rig, RigCamera, default_rig
from fisheye_infer.cli import main
from fisheye_infer.errors import ArtifactError, FrameError, RigError
from fisheye_infer.export.graph import get_metadata
from fisheye_infer.export.image_entry import IMAGE_ENTRY_KEY
from fisheye_infer.export.rebake import rebake
from fisheye_infer.export.virtual_front import attach_front, detach_front, has_front
from fisheye_infer.geometry.virtual import virtual_front
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.scenes.render import Renderer, random_scene, resized_rig
from fisheye_infer.tools.virtual_picture import resample_views

TRAINING = resized_rig(default_rig(), 0.1)  # four 80x80 OCam cameras


def _turned(camera: RigCamera, pitch_deg: float, roll_deg: float) -> np.ndarray:
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(p), -math.sin(p)], [0, math.sin(p), math.cos(p)]])
    rz = np.array([[math.cos(r), -math.sin(r), 0], [math.sin(r), math.cos(r), 0], [0, 0, 1]])
    m = camera.matrix.copy()
    m[:3, :3] = m[:3, :3] @ rx @ rz
    return m


def _lens(kind: str) -> object:
    """A robot lens of each model, its 200-odd-degree field scaled into its own image."""
    ocam = TRAINING.cameras[0].model
    assert isinstance(ocam, OCamModel)
    return {
        "ocam": ocam.model_copy(update={"center_row": ocam.center_row + 1.0, "center_col": ocam.center_col - 1.0}),
        "kannala_brandt": KannalaBrandt(
            width=96, height=72, fx=22.0, fy=22.0, cx=47.5, cy=35.5, k=(0.01, 0.0, 0.0, 0.0)
        ),
        "equidistant": Equidistant(width=80, height=80, fx=20.0, fy=20.0, cx=39.5, cy=39.5),
        "double_sphere": DoubleSphere(
            width=80, height=80, fx=17.0, fy=17.0, cx=39.5, cy=39.5, xi=-0.17, alpha=0.59, fov=220.0
        ),
        "eucm": ExtendedUnified(
            width=96, height=72, fx=18.0, fy=18.0, cx=47.5, cy=35.5, alpha=0.61, beta=1.07, fov=220.0
        ),
        "omnidirectional": Omnidirectional(
            width=80,
            height=80,
            xi=1.7,
            fx=60.0,
            fy=60.0,
            cx=39.5,
            cy=39.5,
            distortion=(-0.1, 0.02, 0.0, 0.0),
            fov=220.0,
        ),
        "distorted_pinhole": DistortedPinhole(
            width=120, height=90, fx=40.0, fy=40.0, cx=59.5, cy=44.5, distortion=(-0.1, 0.01, 0.0, 0.0)
        ),
    }[kind]


def _robot(kind: str) -> Rig:
    """The training rig's cameras renamed cam0..cam3, listed in reverse, the front one with ``kind``'s lens and
    pitched 5 and rolled 3 degrees on its mount."""
    cameras = []
    for i, cam in enumerate(TRAINING.cameras):
        model, pose = (_lens(kind), _turned(cam, 5.0, 3.0)) if i == 0 else (cam.model, cam.matrix)
        cameras.append(RigCamera(name=f"cam{i}", model=model, cam2lidar=tuple(map(tuple, pose.tolist()))))
    return Rig(name=f"robot-{kind}", cameras=tuple(reversed(cameras)))


def _reference(training: RigCamera, robot: RigCamera, image: np.ndarray) -> np.ndarray:
    """The training camera's picture resampled from ``image`` with numpy and cv2.remap alone."""
    model = training.model
    v, u = np.mgrid[0 : model.height, 0 : model.width]
    rays = model.unproject(np.stack([u.ravel(), v.ravel()], axis=1).astype(np.float64))
    inside = incidence_angle(np.nan_to_num(rays)) <= math.radians(model.fov / 2)
    turned = rays @ (robot.matrix[:3, :3].T @ training.matrix[:3, :3]).T
    uv, valid = robot.model.project(np.where(inside[:, None], turned, 0.0))
    seen = inside & valid
    maps = np.where(seen[:, None], uv, -1.0).astype(np.float32).reshape(model.height, model.width, 2)
    fixed = cv2.convertMaps(maps[..., 0], maps[..., 1], cv2.CV_16SC2)  # OpenCV 4.x's 1/32 px fixed-point maps
    out = cv2.remap(image, *fixed, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)
    out[(inside & ~seen).reshape(model.height, model.width)] = 128
    return out


def _identity_graph(n: int, height: int, width: int) -> onnx.ModelProto:
    """A network that returns its camera images cast to float, as every exported network's first step casts them."""
    images = helper.make_tensor_value_info("images", TensorProto.UINT8, ["batch", n, height, width, 3])
    out = helper.make_tensor_value_info("seen", TensorProto.FLOAT, None)
    cast = helper.make_node("Cast", ["images"], ["seen"], to=TensorProto.FLOAT)
    graph = helper.make_graph([cast], "identity", [images], [out])
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


@pytest.mark.parametrize(
    "kind", ["ocam", "kannala_brandt", "equidistant", "double_sphere", "eucm", "omnidirectional", "distorted_pinhole"]
)
def test_front_end_equals_an_independent_cv2_remap(kind: str) -> None:
    """Each slot's picture equals the reference to the bit, for robot cameras of each model and size."""
    robot = _robot(kind)
    order = map_cameras(TRAINING, robot)
    front = virtual_front(TRAINING, robot, order)
    proto = _identity_graph(len(TRAINING), 80, 80)
    attach_front(proto, front)
    pw, ph = front.padded_size
    rng = np.random.default_rng(7)
    raw = {
        name: rng.integers(0, 256, (robot.camera(name).model.height, robot.camera(name).model.width, 3), np.uint8)
        for name in order
    }
    batch = np.zeros((2, len(order), ph, pw, 3), np.uint8)
    for i, name in enumerate(order):
        h, w = raw[name].shape[:2]
        batch[0, i, :h, :w] = raw[name]
        batch[1, i, :h, :w] = 255 - raw[name]
    session = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"images": batch})
    assert got.shape == (2, len(order), 80, 80, 3)
    for i, (slot, name) in enumerate(zip(TRAINING.cameras, order)):
        np.testing.assert_array_equal(got[0, i], _reference(slot, robot.camera(name), raw[name]), err_msg=slot.name)
        np.testing.assert_array_equal(got[1, i], _reference(slot, robot.camera(name), 255 - raw[name]))
    np.testing.assert_array_equal(np.stack(resample_views(front, raw)), got[0])  # the picture's numpy path
    turn = np.linalg.inv(TRAINING.cameras[0].matrix) @ _turned(TRAINING.cameras[0], 5.0, 3.0)
    expected = math.degrees(math.acos((np.trace(turn[:3, :3]) - 1) / 2))
    assert front.reports[0].rotation_deg == pytest.approx(expected, abs=1e-3)


def test_front_end_detaches_to_the_original_graph() -> None:
    proto = _identity_graph(4, 80, 80)
    before = proto.SerializeToString()
    attach_front(proto, virtual_front(TRAINING, _robot("eucm"), map_cameras(TRAINING, _robot("eucm"))))
    assert has_front(proto)
    detach_front(proto)
    assert not has_front(proto) and proto.SerializeToString() == before


MEAN = np.array([103.53, 116.28, 123.675], np.float32)


def _entry_graph(n: int, height: int, width: int, tiled_mean: np.ndarray) -> onnx.ModelProto:
    """A network that starts as ``normalise_frames`` exports it: cast, mean subtracted along rows of W*3,
    channels-first."""
    images = helper.make_tensor_value_info("images", TensorProto.UINT8, ["batch", n, height, width, 3])
    out = helper.make_tensor_value_info("seen", TensorProto.FLOAT, None)
    nodes = [
        helper.make_node("Cast", ["images"], ["f"], name="cast", to=TensorProto.FLOAT),
        helper.make_node("Reshape", ["f", "rows_shape"], ["rows"], name="rows"),
        helper.make_node("Sub", ["rows", "tiled_mean"], ["centred"], name="sub"),
        helper.make_node("Reshape", ["centred", "pixels_shape"], ["pixels"], name="pixels"),
        helper.make_node("Transpose", ["pixels"], ["planes"], name="planes", perm=[0, 3, 1, 2]),
        helper.make_node("Identity", ["planes"], ["seen"], name="network"),
    ]
    inits = [
        numpy_helper.from_array(np.array([-1, height, width * 3], np.int64), "rows_shape"),
        numpy_helper.from_array(tiled_mean, "tiled_mean"),
        numpy_helper.from_array(np.array([-1, height, width, 3], np.int64), "pixels_shape"),
    ]
    graph = helper.make_graph(nodes, "entry", [images], [out], inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])


def test_the_front_end_takes_over_the_networks_image_entry() -> None:
    """The front end writes the entry's channels-first, mean-subtracted planes itself: equal to the reference
    normalised as the entry does, to the bit; detached, the graph is the original to the byte."""
    robot = _robot("kannala_brandt")
    order = map_cameras(TRAINING, robot)
    front = virtual_front(TRAINING, robot, order)
    proto = _entry_graph(len(TRAINING), 80, 80, np.tile(MEAN, 80))
    before = proto.SerializeToString()
    attach_front(proto, front)
    assert {"cast", "rows", "sub", "pixels", "planes"}.isdisjoint(node.name for node in proto.graph.node)
    assert not any(node.op_type == "Transpose" and len(node.attribute[0].ints) == 5 for node in proto.graph.node)
    pw, ph = front.padded_size
    rng = np.random.default_rng(3)
    sizes = {name: (robot.camera(name).model.height, robot.camera(name).model.width, 3) for name in order}
    raw = {name: rng.integers(0, 256, size, np.uint8) for name, size in sizes.items()}
    batch = np.zeros((2, len(order), ph, pw, 3), np.uint8)
    for i, name in enumerate(order):
        h, w = raw[name].shape[:2]
        batch[0, i, :h, :w], batch[1, i, :h, :w] = raw[name], 255 - raw[name]
    session = ort.InferenceSession(proto.SerializeToString(), providers=["CPUExecutionProvider"])
    (got,) = session.run(None, {"images": batch})
    assert got.shape == (2 * len(order), 3, 80, 80)
    for b, flip in enumerate([False, True]):
        for i, (slot, name) in enumerate(zip(TRAINING.cameras, order)):
            seen = _reference(slot, robot.camera(name), 255 - raw[name] if flip else raw[name])
            expected = (seen.astype(np.float32) - MEAN).transpose(2, 0, 1)
            np.testing.assert_array_equal(got[b * len(order) + i], expected, err_msg=f"{slot.name}, frame {b}")
    detach_front(proto)
    assert proto.SerializeToString() == before


def test_a_network_that_starts_otherwise_gets_the_images_channels_last() -> None:
    """A mean that is not one value per channel is not the exported entry: the network keeps its own."""
    tiled = np.tile(MEAN, 80)
    tiled[5] += 1.0
    proto = _entry_graph(len(TRAINING), 80, 80, tiled)
    attach_front(proto, virtual_front(TRAINING, _robot("eucm"), map_cameras(TRAINING, _robot("eucm"))))
    assert {"cast", "rows", "sub", "pixels", "planes"} <= {node.name for node in proto.graph.node}


def test_the_front_end_passes_the_tensorrt_check() -> None:
    """UINT8 only at the graph's edge: the front end casts the robot's images first and hands float32 on."""
    from fisheye_infer.export.tensorrt_check import check_tensorrt

    proto = _identity_graph(4, 80, 80)
    attach_front(proto, virtual_front(TRAINING, _robot("eucm"), map_cameras(TRAINING, _robot("eucm"))))
    report = check_tensorrt(proto)
    assert report.compatible, [f.message for f in report.findings if f.severity == "error"]


def test_a_network_that_reads_its_images_as_uint8_is_refused() -> None:
    images = helper.make_tensor_value_info("images", TensorProto.UINT8, ["batch", 4, 80, 80, 3])
    out = helper.make_tensor_value_info("seen", TensorProto.UINT8, None)
    graph = helper.make_graph([helper.make_node("Identity", ["images"], ["seen"], name="raw")], "g", [images], [out])
    proto = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)])
    before = proto.SerializeToString()
    with pytest.raises(ArtifactError, match="node 'raw' \\(Identity\\) reads the camera images as they are"):
        attach_front(proto, virtual_front(TRAINING, _robot("ocam"), map_cameras(TRAINING, _robot("ocam"))))
    assert proto.SerializeToString() == before


def test_a_narrower_lens_leaves_unseen_pixels_grey_and_says_how_much_it_covers() -> None:
    narrow = Equidistant(width=80, height=80, fx=30.0, fy=30.0, cx=39.5, cy=39.5, fov=160.0)
    robot = TRAINING.model_copy(
        update={"cameras": tuple(c.model_copy(update={"model": narrow}) for c in TRAINING.cameras)}
    )
    front = virtual_front(TRAINING, robot, robot.names)
    view, report = front.views[0], front.reports[0]
    assert 0.3 < report.coverage < 0.9
    assert report.coverage == pytest.approx(view.seen.sum() / view.inside_lens.sum(), abs=1e-6)
    fill = front.tables["geom.virtual.fill"][0].reshape(80, 80)
    assert set(np.unique(fill[view.unseen])) == {128.0} and not fill[~view.unseen].any()
    assert "covers" in report.summary()


# -- mapping cameras onto the model's ------------------------------------------------------------------------


def test_cameras_map_by_heading_not_by_file_order() -> None:
    robot = _robot("ocam")  # cam3, cam2, cam1, cam0: the reverse of the model's order
    assert map_cameras(TRAINING, robot) == ["cam0", "cam1", "cam2", "cam3"]


def test_an_explicit_map_is_followed_and_checked() -> None:
    robot = _robot("ocam")
    explicit = parse_camera_map(
        "fisheye_camera_front=cam0, fisheye_camera_left=cam1,fisheye_camera_right=cam2,fisheye_camera_rear=cam3"
    )
    assert map_cameras(TRAINING, robot, explicit) == ["cam0", "cam1", "cam2", "cam3"]
    with pytest.raises(RigError, match="no robot camera given for fisheye_camera_rear"):
        map_cameras(TRAINING, robot, {k: v for k, v in explicit.items() if k != "fisheye_camera_rear"})
    with pytest.raises(RigError, match="'cam9' is not a camera of the robot rig"):
        map_cameras(TRAINING, robot, {**explicit, "fisheye_camera_rear": "cam9"})
    with pytest.raises(RigError, match="robot camera 'cam0' would stand in fisheye_camera_front, fisheye_camera_rear"):
        map_cameras(TRAINING, robot, {**explicit, "fisheye_camera_rear": "cam0"})
    with pytest.raises(RigError, match="not 'model_camera=robot_camera'"):
        parse_camera_map("fisheye_camera_front:cam0")


def test_two_cameras_looking_the_same_way_are_refused_with_the_candidates() -> None:
    front = TRAINING.cameras[0]
    cameras = [c.model_copy(update={"name": f"c{i}"}) for i, c in enumerate(TRAINING.cameras)]
    cameras[3] = front.model_copy(update={"name": "c3"})  # a second forward camera, none looking back
    with pytest.raises(RigError, match=r"fisheye_camera_front': 2 robot cameras .*c0 \(0°\), c3 \(0°\).*--camera-map"):
        map_cameras(TRAINING, Rig(name="two-front", cameras=tuple(cameras)))


# -- files ---------------------------------------------------------------------------------------------------


def _frame(rig: Rig) -> dict[str, np.ndarray]:
    return Renderer(texture_seed=3).render(rig, random_scene(np.random.default_rng(11)))


def test_virtual_cameras_on_the_training_rig_answer_as_the_unchanged_file(small_export, tmp_path: Path) -> None:
    meta = read_meta(small_export.onnx)
    out = rebake(small_export.onnx, meta.rig, tmp_path / "virtual.onnx", mode="virtual")
    assert out.virtual_cameras is not None and out.parity == meta.parity
    assert IMAGE_ENTRY_KEY in get_metadata(onnx.load(str(tmp_path / "virtual.onnx")))  # the entry taken over
    assert all(r.coverage == 1.0 and r.rotation_deg == 0.0 for r in out.virtual_cameras.cameras)
    assert meta.tensorrt is not None and meta.tensorrt.compatible
    assert out.tensorrt is not None and out.tensorrt.compatible, out.tensorrt
    frame = _frame(meta.rig)
    plain, virtual = Detector(small_export.onnx, threads=1), Detector(tmp_path / "virtual.onnx", threads=1)
    a, b = plain.detect(frame), virtual.detect(frame)
    np.testing.assert_array_equal(a.boxes, b.boxes)
    np.testing.assert_array_equal(a.scores, b.scores)


def test_each_robot_camera_is_fed_at_its_own_size_and_by_its_own_name(small_export, tmp_path: Path) -> None:
    meta = read_meta(small_export.onnx)
    eucm = ExtendedUnified(width=200, height=150, fx=37.0, fy=37.0, cx=99.5, cy=74.5, alpha=0.61, beta=1.07, fov=220.0)
    cameras = [c.model_copy(update={"name": f"robot_{i}"}) for i, c in enumerate(meta.rig.cameras)]
    cameras[2] = cameras[2].model_copy(update={"model": eucm})
    robot = Rig(name="robot", cameras=tuple(reversed(cameras)))
    robot.save(tmp_path / "robot.json")
    picture = tmp_path / "views.png"
    argv = ["rebake", str(small_export.onnx), "--rig", str(tmp_path / "robot.json"), "--out", str(tmp_path / "r.onnx")]
    assert main([*argv, "--picture", str(picture)]) == 0
    assert cv2.imread(str(picture)).shape[0] > 4 * 320  # one row of two pictures per camera
    out = read_meta(tmp_path / "r.onnx")
    assert out.cameras == ("robot_0", "robot_1", "robot_2", "robot_3")
    assert out.image_size == (200, 160) and out.camera_sizes()[2] == (200, 150)
    detector = Detector(tmp_path / "r.onnx", threads=1)
    frame = _frame(robot)
    assert frame["robot_2"].shape == (150, 200, 3)
    dets = detector.detect(frame)
    assert dets.cameras_used == ("robot_0", "robot_1", "robot_2", "robot_3")
    with pytest.raises(FrameError, match="camera 'robot_2': image is 160x160, model expects 200x150"):
        detector.detect({**frame, "robot_2": np.zeros((160, 160, 3), np.uint8)})


def test_the_tables_mode_keeps_the_model_cameras(small_export, tmp_path: Path, capsys) -> None:
    meta = read_meta(small_export.onnx)
    moved = meta.rig.model_copy(
        update={
            "cameras": tuple(
                c.model_copy(update={"cam2lidar": tuple(map(tuple, _turned(c, 2.0, 0.0).tolist()))})
                for c in meta.rig.cameras
            )
        }
    )
    moved.save(tmp_path / "moved.json")
    args = ["rebake", str(small_export.onnx), "--rig", str(tmp_path / "moved.json")]
    assert main([*args, "--out", str(tmp_path / "t.onnx"), "--tables"]) == 0
    assert "geometry tables recomputed" in capsys.readouterr().out
    tables = read_meta(tmp_path / "t.onnx")
    assert tables.virtual_cameras is None and tables.image_size == meta.image_size
    assert main([*args, "--out", str(tmp_path / "v.onnx")]) == 0
    printed = capsys.readouterr().out
    assert "virtual cameras" in printed and "rotation 2.00° compensated" in printed
    # a virtual file re-targeted with --tables loses its front end
    assert (
        main(
            [
                "rebake",
                str(tmp_path / "v.onnx"),
                "--rig",
                str(tmp_path / "moved.json"),
                "--out",
                str(tmp_path / "tv.onnx"),
                "--tables",
            ]
        )
        == 0
    )
    detached = onnx.load(str(tmp_path / "tv.onnx"))
    assert not has_front(detached) and IMAGE_ENTRY_KEY not in get_metadata(detached)
    assert [n.name for n in detached.graph.node] == [n.name for n in onnx.load(str(tmp_path / "t.onnx")).graph.node]
    assert main([*args, "--out", str(tmp_path / "x.onnx"), "--tables", "--camera-map", "a=b"]) == 1
    assert "--tables keeps the model's cameras" in capsys.readouterr().err


def test_export_onto_retargets_each_written_file_in_place(small_export, tmp_path: Path, capsys) -> None:
    """``export --onto``'s last step: every file it wrote, re-targeted where it lies."""
    import argparse
    import shutil

    from fisheye_infer.commands.export import _onto

    meta = read_meta(small_export.onnx)
    robot = meta.rig.model_copy(
        update={"cameras": tuple(c.model_copy(update={"name": f"r{i}"}) for i, c in enumerate(meta.rig.cameras))}
    )
    robot.save(tmp_path / "robot.json")
    path = Path(shutil.copy(small_export.onnx, tmp_path / "model.onnx"))
    args = argparse.Namespace(onto=str(tmp_path / "robot.json"), camera_map=None, depth=None)
    assert _onto(args, [path]) == 0
    assert read_meta(path).cameras == ("r0", "r1", "r2", "r3") and "virtual cameras onto" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir()) == ["model.onnx", "robot.json"]


def test_fisheye_petr_masks_the_keys_a_narrower_lens_does_not_see(small_exports, tmp_path: Path) -> None:
    exported = small_exports("fisheye-petr")
    meta = read_meta(exported.onnx)

    def key_mask(path: Path) -> np.ndarray:
        return next(
            onnx.numpy_helper.to_array(i)
            for i in onnx.load(str(path)).graph.initializer
            if i.name == "geom.petr.key_mask"
        )

    same = rebake(exported.onnx, meta.rig, tmp_path / "same.onnx", mode="virtual")
    assert same.virtual_cameras is not None
    np.testing.assert_array_equal(key_mask(tmp_path / "same.onnx"), key_mask(exported.onnx))
    side = meta.rig.cameras[0].model.width
    narrow = Equidistant(
        width=side, height=side, fx=side / 4, fy=side / 4, cx=(side - 1) / 2, cy=(side - 1) / 2, fov=150.0
    )
    robot = meta.rig.model_copy(
        update={"cameras": tuple(c.model_copy(update={"model": narrow}) for c in meta.rig.cameras)}
    )
    rebake(exported.onnx, robot, tmp_path / "narrow.onnx")
    before, after = key_mask(exported.onnx), key_mask(tmp_path / "narrow.onnx")
    assert (after >= before).all() and after.sum() > before.sum() + 0.1 * before.size
    frame = _frame(robot)
    assert Detector(tmp_path / "narrow.onnx", threads=1).detect(frame).boxes.shape[1] == 7


@pytest.mark.parametrize("arch", ["pinhole-bevdet", "fisheye-bevdet-cyl"])
def test_baselines_take_virtual_cameras_too(arch: str, small_exports, tmp_path: Path) -> None:
    """The pinhole and rectified baselines: identity on their training rig; a robot rig of other intrinsics, sizes
    and distortion (pinhole) or other lenses (fisheye) runs with each camera at its own size."""
    exported = small_exports(arch)
    meta = read_meta(exported.onnx)
    same = tmp_path / "same.onnx"
    rebake(exported.onnx, meta.rig, same, mode="virtual")
    frame = _frame(meta.rig)
    a, b = Detector(exported.onnx, threads=1).detect(frame), Detector(same, threads=1).detect(frame)
    np.testing.assert_array_equal(a.boxes, b.boxes)
    if arch.startswith("pinhole"):
        w, h = meta.rig.cameras[0].model.width, meta.rig.cameras[0].model.height
        lens = DistortedPinhole(
            width=w + 40,
            height=h + 30,
            fx=w * 0.55,
            fy=w * 0.55,
            cx=(w + 39) / 2,
            cy=(h + 29) / 2,
            distortion=(-0.05, 0.01, 0.0, 0.0),
        )
    else:
        lens = KannalaBrandt(width=640, height=480, fx=125.0, fy=125.0, cx=319.5, cy=239.5, k=(0.01, 0.0, 0.0, 0.0))
    robot = meta.rig.model_copy(
        update={
            "cameras": tuple(c.model_copy(update={"model": lens, "name": f"robot_{c.name}"}) for c in meta.rig.cameras)
        }
    )
    out = rebake(exported.onnx, robot, tmp_path / "robot.onnx")
    assert out.virtual_cameras is not None and all(r.coverage > 0.9 for r in out.virtual_cameras.cameras)
    dets = Detector(tmp_path / "robot.onnx", threads=1).detect(_frame(robot))
    assert dets.boxes.shape[1] == 7 and len(dets.cameras_used) == len(robot)


def test_rebake_refuses_what_is_not_a_regular_file(tmp_path: Path) -> None:
    with pytest.raises(ArtifactError, match="/dev/zero: no such file"):
        rebake("/dev/zero", TRAINING, tmp_path / "x.onnx")


def test_the_front_end_counts_with_the_image_trunk(small_export, tmp_path: Path) -> None:
    """Stage timing and int8's region: the resampling belongs to the image trunk, ahead of the backbone."""
    from fisheye_infer.export.graph_stages import image_region, name_nodes

    rebake(small_export.onnx, _robot_of(small_export), tmp_path / "v.onnx")
    proto = onnx.load(str(tmp_path / "v.onnx"))
    name_nodes(proto)
    region = image_region(proto)
    assert {f"virtual_front/gather{c}" for c in range(3)} <= set(region)
    assert any(name.startswith("virtual_front/") is False and "Conv" in name for name in region)


def _robot_of(exported) -> Rig:
    rig = read_meta(exported.onnx).rig
    return rig.model_copy(
        update={"cameras": tuple(c.model_copy(update={"name": f"r{i}"}) for i, c in enumerate(rig.cameras))}
    )
