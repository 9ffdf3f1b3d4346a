"""The pinhole baselines: pinhole-bevdet / pinhole-petr (``nusc_*``, six pinhole cameras) and
fisheye-bevdet-persp / fisheye-petr-persp (``fisheye_to_pinhole_*``, eight perspective views of four
fisheye cameras).

Each image front end is compared with the tool the official pipeline calls (Pillow's resize, cv2's
remap), the geometry with the official formulas computed independently here (the LSS
``get_geometry`` and PETR's ``position_embeding`` in float32 torch, scipy's rotation), and the kit
checkpoints export with a passing self-check at full size.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch
from checkpoint_kit import kit_checkpoint
from small_configs import PINHOLE_RIG, small_configs  # noqa: E402

from fisheye_infer.cameras.rig import PINHOLE_CAMERAS, Rig, default_rig, resolve_rig
from fisheye_infer.errors import ConfigError, RigError
from fisheye_infer.eval.dataset import PINHOLE_MODEL, DatasetError, Fisheye3DOD
from fisheye_infer.eval.evaluate import detect_dataset, evaluate_results
from fisheye_infer.export.exporter import export, infer_architecture
from fisheye_infer.export.rebake import rebake
from fisheye_infer.geometry.pinhole_lss import view_points
from fisheye_infer.geometry.pinhole_petr import view_coords
from fisheye_infer.geometry.pooling import BevGrid, voxelise
from fisheye_infer.geometry.tables import RECTIFY
from fisheye_infer.geometry.views import Perspective, ResizeCrop, perspective_intrinsics, views_of, yaw_rotation
from fisheye_infer.models import (
    PerspBEVDetConfig,
    PerspPETRConfig,
    PinholeBEVDetConfig,
    PinholePETRConfig,
    create_model,
    load_checkpoint,
    matching_architectures,
)
from fisheye_infer.models.cylindrical import rectify
from fisheye_infer.runtime.artifact import read_meta
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import Renderer, random_scene, resized_rig, synthesize

DATA = Path(__file__).parent / "data"
PINHOLE, PERSP = "pinhole-bevdet", "fisheye-bevdet-persp"
PINHOLE_PETR, PERSP_PETR = "pinhole-petr", "fisheye-petr-persp"
#: The released config file of each architecture.
CONFIGS = {
    PINHOLE: "nusc_bevdet.py",
    PERSP: "fisheye_to_pinhole_bevdet.py",
    PINHOLE_PETR: "nusc_petr.py",
    PERSP_PETR: "fisheye_to_pinhole_petr.py",
}
REDUCED = small_configs()


@pytest.fixture(scope="module")
def pinhole_rig() -> Rig:
    return resolve_rig(PINHOLE_RIG)


# -- configurations ------------------------------------------------------------------------------


def test_released_configs_are_the_defaults() -> None:
    nusc = PinholeBEVDetConfig.from_mmdet3d_config(DATA / "nusc_bevdet.py")
    persp = PerspBEVDetConfig.from_mmdet3d_config(DATA / "fisheye_to_pinhole_bevdet.py")
    assert nusc == PinholeBEVDetConfig() and persp == PerspBEVDetConfig()
    # ImageAug3D in test mode: 1280x720 * 0.625 = 800x450, the bottom 400 rows kept, centred columns
    assert (nusc.image_aug.scale, nusc.image_aug.crop) == (0.625, (0, 50))
    assert nusc.image.camera_names == PINHOLE_CAMERAS and (nusc.image.width, nusc.image.height) == (1280, 720)
    assert nusc.view_transform.image_size == (400, 800) and nusc.view_transform.feature_size == (25, 50)
    assert persp.perspective.size == (400, 400) and persp.perspective.fov == 110 and persp.perspective.yaws == (-55, 55)
    assert persp.perspective.truncate and persp.view_transform.feature_size == (25, 25)
    assert (
        PinholeBEVDetConfig.from_dict(nusc.to_dict()) == nusc and PerspBEVDetConfig.from_dict(persp.to_dict()) == persp
    )


def test_released_petr_configs_are_the_defaults() -> None:
    """Read as released: nusc_petr.py lacks 'img_shape' in its meta_keys and fisheye_to_pinhole_petr.py packs one
    shape for all views (both crash in the official test path); neither matters to what the exporter reads."""
    nusc = PinholePETRConfig.from_mmdet3d_config(DATA / "nusc_petr.py")
    persp = PerspPETRConfig.from_mmdet3d_config(DATA / "fisheye_to_pinhole_petr.py")
    assert nusc == PinholePETRConfig() and persp == PerspPETRConfig()
    # ResizeCropFlipImage in test mode: scale max(400 / 720, 800 / 1280) = 0.625, the same crop as BEVDet's
    assert (nusc.image_aug.scale, nusc.image_aug.crop) == (0.625, (0, 50)) and nusc.head.feature_size == (25, 50)
    assert persp.perspective.yaws == (-55, 55) and not persp.perspective.truncate and persp.num_views == 8
    assert PinholePETRConfig.from_dict(nusc.to_dict()) == nusc and PerspPETRConfig.from_dict(persp.to_dict()) == persp


@pytest.mark.parametrize(
    ("reader", "config", "message"),
    [
        (PinholeBEVDetConfig, "fisheye_to_pinhole_bevdet.py", "fisheye-bevdet-persp configuration"),
        (PerspBEVDetConfig, "nusc_bevdet.py", "no MultiViewFisheyePerspectiveProjection step"),
        (PinholeBEVDetConfig, "fisheye_to_cyl_bevdet.py", "'CylindricalLSSTransform', expected 'LSSTransform'"),
        (PinholePETRConfig, "fisheye_to_pinhole_petr.py", "fisheye-petr-persp configuration"),
        (PerspPETRConfig, "nusc_petr.py", "no MultiViewFisheyePerspectiveProjection step"),
        (PinholePETRConfig, "fisheye_to_cyl_petr.py", "no ResizeCropFlipImage step"),
    ],
)
def test_each_reader_refuses_the_other_configs(reader: type, config: str, message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        reader.from_mmdet3d_config(DATA / config)


def test_a_crop_outside_the_resized_image_is_refused() -> None:
    with pytest.raises(
        ConfigError, match=r"image_aug: a 800x400 crop at \(left, top\)=\(0, 60\) does not fit the 800x450 image"
    ):
        PinholeBEVDetConfig().replace(image_aug={"crop": (0, 60)})


# -- the pinhole rig file ------------------------------------------------------------------------


def test_the_pinhole_rig_file_is_read(pinhole_rig: Rig) -> None:
    doc = json.loads(PINHOLE_RIG.read_text())
    assert pinhole_rig.names == list(PINHOLE_CAMERAS)
    for cam, entry in zip(pinhole_rig.cameras, doc["cameras"]):
        m = cam.model
        assert (m.type, m.width, m.height, m.fx, m.fy, m.cx, m.cy) == ("pinhole", 1280, 720, 640.0, 640.0, 640.0, 360.0)
        np.testing.assert_allclose(cam.matrix @ np.array(entry["lidar2cam"]), np.eye(4), atol=1e-12)
        np.testing.assert_allclose(cam.position, entry["position_lidar"], atol=1e-12)
        assert (
            math.degrees(cam.heading)
            == pytest.approx(entry["heading_deg"] if entry["heading_deg"] != 180 else 180.0, abs=1e-9)
            or abs(abs(math.degrees(cam.heading)) - 180) < 1e-9
        )


@pytest.mark.parametrize(
    ("field", "value", "message"),
    [
        ("distortion", "plumb_bob", r"camera 'nu_rgb_camera_front_left' \(distortion\): 'plumb_bob' is not supported"),
        (
            "K",
            [[640.0, 1.0, 640.0], [0.0, 640.0, 360.0], [0.0, 0.0, 1.0]],
            r"camera 'nu_rgb_camera_front_left' \(K\): expected \[\[fx, 0, cx\]",
        ),
        (
            "lidar2cam",
            [[1.0, 0.0], [0.0, 1.0]],
            r"camera 'nu_rgb_camera_front_left' \(lidar2cam\): expected a finite 4x4 matrix",
        ),
    ],
)
def test_a_pinhole_rig_file_names_the_bad_camera(tmp_path: Path, field: str, value: object, message: str) -> None:
    doc = json.loads(PINHOLE_RIG.read_text())
    doc["cameras"][1][field] = value
    path = tmp_path / "cameras.json"
    path.write_text(json.dumps(doc))
    with pytest.raises(RigError, match=message):
        resolve_rig(path)


# -- views ---------------------------------------------------------------------------------------


@pytest.mark.parametrize("yaw", [-55.0, 55.0, 30.0, -110.0])
def test_yaw_rotation_is_scipys(yaw: float) -> None:
    rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    np.testing.assert_array_equal(yaw_rotation(yaw), rotation.from_euler("y", yaw, degrees=True).as_matrix())


def test_perspective_views_turn_each_fisheye(rig: Rig) -> None:
    views = views_of(rig, Perspective())
    assert len(views) == 8
    for i, (c2l, yaw) in enumerate(zip(np.repeat(rig.cam2lidar(), 2, axis=0), (-55.0, 55.0) * 4)):
        r = np.eye(4)
        r[:3, :3] = yaw_rotation(yaw)
        np.testing.assert_array_equal(views.cam2lidar[i], c2l @ r)
        axis_in_fisheye = yaw_rotation(yaw) @ np.array([0.0, 0.0, 1.0])
        assert (axis_in_fisheye[0] < 0) == (yaw < 0)  # -55 degrees looks to the fisheye's left (camera x points right)
    f = np.float32(200.0 / np.tan(np.radians(55.0)))
    np.testing.assert_array_equal(views.intrinsics[0], [[f, 0, 200], [0, f, 200], [0, 0, 1]])
    np.testing.assert_array_equal(perspective_intrinsics((400, 400), 110.0), views.intrinsics[5])


def _official_points(frustum: np.ndarray, views) -> np.ndarray:  # noqa: ANN001
    """The official ``BaseViewTransform.get_geometry`` in float32 torch on the views' float32 matrices."""
    f32 = lambda a: torch.tensor(np.asarray(a, np.float32))  # noqa: E731
    n = len(views)
    k, post, shift = f32(views.intrinsics), f32(views.post_rotation), f32(views.post_translation)
    rots, trans = f32(views.cam2lidar[:, :3, :3]), f32(views.cam2lidar[:, :3, 3])
    points = torch.from_numpy(frustum) - shift.view(1, n, 1, 1, 1, 3)
    points = torch.inverse(post).view(1, n, 1, 1, 1, 3, 3).matmul(points.unsqueeze(-1))
    points = torch.cat((points[..., :2, :] * points[..., 2:3, :], points[..., 2:3, :]), -2)
    points = rots.matmul(torch.inverse(k)).view(1, n, 1, 1, 1, 3, 3).matmul(points).squeeze(-1)
    return (points + trans.view(1, n, 1, 1, 1, 3))[0].numpy()


@pytest.mark.parametrize(("arch", "most_moved"), [(PINHOLE, 0), (PERSP, 2)])
def test_points_follow_the_official_float32_arithmetic(arch: str, most_moved: int, pinhole_rig: Rig, rig: Rig) -> None:
    """The pooling plan's cells are the official model's, but for points on a cell border that float32 rounding moves."""
    with np.load(Path(__file__).parents[1] / "data" / "checkpoints" / arch / "geometry.npz") as npz:
        frustum = npz["view_transform.frustum"]
    views = (
        views_of(pinhole_rig, ResizeCrop(scale=0.625, crop=(0, 50)))
        if arch == PINHOLE
        else views_of(rig, Perspective())
    )
    ours, official = view_points(frustum, views), _official_points(frustum, views)
    np.testing.assert_allclose(ours, official, rtol=0, atol=5e-5)
    grid = BevGrid()
    (cells, kept), (ref_cells, ref_kept) = voxelise(ours, grid), voxelise(official, grid)
    assert kept.sum() > 1e5
    assert (kept != ref_kept).sum() + ((cells != ref_cells) & kept & ref_kept).sum() <= most_moved


def test_pinhole_points_project_back_to_their_pixels(pinhole_rig: Rig) -> None:
    """A frustum point of view pixel (x, y) lies on the camera ray of pixel ((x, y) + crop) / scale, at depth d."""
    params = PinholeBEVDetConfig().geometry_params()
    frustum = params.frustum()
    points = view_points(frustum, views_of(pinhole_rig, params.views)).astype(np.float64)
    for v, cam in enumerate(pinhole_rig.cameras):
        p = points[v].reshape(-1, 3)
        cam_frame = (np.linalg.inv(cam.matrix) @ np.c_[p, np.ones(len(p))].T).T[:, :3]
        uv, valid = cam.model.project(cam_frame)
        expected = (frustum[..., :2].reshape(-1, 2) + (0, 50)) / 0.625
        np.testing.assert_allclose(uv, expected, atol=2e-3)
        np.testing.assert_allclose(cam_frame[:, 2], frustum[..., 2].reshape(-1), rtol=1e-5)
        assert valid.all()


def test_pinhole_lidar2img_is_the_official_cam2img_update(pinhole_rig: Rig) -> None:
    """ResizeCropFlipImage: cam2img[:3, :3] = ida @ K; PETR.add_lidar2img: lidar2img = viewpad(cam2img) @ lidar2cam."""
    views = views_of(pinhole_rig, ResizeCrop(scale=0.625, crop=(0, 50)))
    ida = np.array([[0.625, 0, 0], [0, 0.625, -50], [0, 0, 1]])
    for cam, lidar2img in zip(pinhole_rig.cameras, views.lidar2img()):
        m = cam.model
        pad = np.eye(4)
        pad[:3, :3] = ida @ np.array([[m.fx, 0, m.cx], [0, m.fy, m.cy], [0, 0, 1]])
        np.testing.assert_allclose(lidar2img, pad @ np.linalg.inv(cam.matrix), rtol=0, atol=1e-9)


def _official_coords(lidar2img: np.ndarray, pad_hw: tuple[int, int], feature_hw: tuple[int, int]) -> np.ndarray:
    """The official ``PETRHead.position_embeding`` up to the position encoder, in float32 torch (LID, 64 depths)."""
    eps, (pad_h, pad_w), (h, w), depth_num, start, rng = (
        1e-5,
        pad_hw,
        feature_hw,
        64,
        0.5,
        (-60, -60, -10.0, 60, 60, 10.0),
    )
    coords_h = torch.arange(h).float() * pad_h / h
    coords_w = torch.arange(w).float() * pad_w / w
    index = torch.arange(start=0, end=depth_num, step=1).float()
    bin_size = (rng[3] - start) / (depth_num * (1 + depth_num))
    coords_d = start + bin_size * index * (index + 1)
    coords = torch.stack(torch.meshgrid([coords_w, coords_h, coords_d], indexing="ij")).permute(1, 2, 3, 0)
    coords = torch.cat((coords, torch.ones_like(coords[..., :1])), -1)
    coords[..., :2] = coords[..., :2] * torch.maximum(coords[..., 2:3], torch.ones_like(coords[..., 2:3]) * eps)
    img2lidars = coords.new_tensor(np.asarray([np.linalg.inv(m) for m in lidar2img]))
    n = len(lidar2img)
    coords = coords.view(1, 1, w, h, depth_num, 4, 1).repeat(1, n, 1, 1, 1, 1, 1)
    img2lidars = img2lidars.view(1, n, 1, 1, 1, 4, 4).repeat(1, 1, w, h, depth_num, 1, 1)
    coords3d = torch.matmul(img2lidars, coords).squeeze(-1)[..., :3]
    for axis in range(3):
        coords3d[..., axis] = (coords3d[..., axis] - rng[axis]) / (rng[axis + 3] - rng[axis])
    coords3d = coords3d.permute(0, 1, 4, 5, 3, 2).contiguous().view(n, -1, h, w).clamp(0, 1)
    return torch.log(coords3d.clamp(min=eps) / (1 - coords3d).clamp(min=eps)).numpy()


@pytest.mark.parametrize("arch", [PINHOLE_PETR, PERSP_PETR])
def test_petr_keys_are_the_official_position_embedding(arch: str, pinhole_rig: Rig, rig: Rig) -> None:
    config = PinholePETRConfig() if arch == PINHOLE_PETR else PerspPETRConfig()
    params = config.geometry_params()
    views = views_of(pinhole_rig if arch == PINHOLE_PETR else rig, params.views)
    ours = view_coords(views.lidar2img(), params)
    official = _official_coords(views.lidar2img(), params.image_size, params.feature_size)
    assert ours.shape == official.shape == (len(views), 3 * 64, *params.feature_size)
    # compared as normalised positions in [0, 1] (the official float32 points of up to 60 m round at ~1e-6);
    # the inverse sigmoid then magnifies that rounding near the range's edges
    sigmoid = lambda x: 1.0 / (1.0 + np.exp(-x.astype(np.float64)))  # noqa: E731
    np.testing.assert_allclose(sigmoid(ours), sigmoid(official), rtol=0, atol=2e-6)
    assert np.median(np.abs(ours - official)) < 1e-5


# -- image front ends ----------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fisheye_frames(rig: Rig) -> np.ndarray:
    frames = Renderer().render(rig, random_scene(np.random.default_rng(5)))
    return np.stack([frames[n] for n in rig.names])


def test_perspective_views_are_cv2s_remap_truncated(rig: Rig, fisheye_frames: np.ndarray) -> None:
    """The official generate_perspective_map, computed here from its formulas with scipy and cv2 (OpenCV 4.x
    fixed-point maps), then ImageAug3D's uint8 cast: the model's views equal it to the bit."""
    rotation = pytest.importorskip("scipy.spatial.transform").Rotation
    config, _ = REDUCED[PERSP]
    model = create_model(PERSP, config, rig)
    h, w = config.perspective.size
    camera = rig.shared_model()
    f = (w / 2) / np.tan(np.radians(110.0) / 2)
    xs, ys = np.meshgrid(np.linspace(-w / 2, w / 2 - 1, w), np.linspace(-h / 2, h / 2 - 1, h))
    rays = np.stack([xs, ys, np.full_like(xs, f)], axis=-1)
    expected = []
    for frame in fisheye_frames:
        for yaw in (-55, 55):
            uv = camera.world2cam((rays @ rotation.from_euler("y", yaw, degrees=True).as_matrix().T).reshape(-1, 3))
            mx, my = (uv[:, i].reshape(h, w).astype(np.float32) for i in (0, 1))
            view = cv2.remap(
                frame.astype(np.float32),
                *cv2.convertMaps(mx, my, cv2.CV_16SC2),
                cv2.INTER_LINEAR,
                borderMode=cv2.BORDER_CONSTANT,
            )
            expected.append(view)
    expected = np.stack(expected)  # camera by camera, yaw by yaw
    tables = model.geometry_tables()
    views = rectify(
        torch.from_numpy(fisheye_frames[None]), tables[RECTIFY + "index"], tables[RECTIFY + "weight"], (2 * h, w)
    )
    views = views[0].reshape(4, 3, 2, h, w).permute(0, 2, 3, 4, 1).reshape(8, h, w, 3).numpy()
    np.testing.assert_array_equal(views, expected)
    with torch.no_grad():
        x = model.normalise(torch.from_numpy(fisheye_frames[None])).permute(0, 2, 3, 1).numpy()
    mean, std = np.array(config.image.mean, np.float32), np.array(config.image.std, np.float32)
    np.testing.assert_allclose(x, (np.floor(expected) - mean) / std, rtol=0, atol=1e-5)
    assert (expected != np.floor(expected)).any()  # the truncation is not a no-op
    petr_config, _ = REDUCED[PERSP_PETR]
    with torch.no_grad():  # PETR's pipeline normalises the float views
        petr = create_model(PERSP_PETR, petr_config, rig)
        y = petr.normalise(torch.from_numpy(fisheye_frames[None]))
        with pytest.warns(
            DeprecationWarning, match="normalize is deprecated"
        ):  # the old name keeps its (B, V, ...) shape
            torch.testing.assert_close(petr.normalize(torch.from_numpy(fisheye_frames[None])), y[None], rtol=0, atol=0)
    np.testing.assert_allclose(y.permute(0, 2, 3, 1).numpy(), (expected - mean) / std, rtol=0, atol=1e-5)


def test_pinhole_views_are_pils_resize_and_crop(pinhole_rig: Rig) -> None:
    """ImageAug3D's Image.fromarray(img, 'RGB').resize((800, 450)).crop((0, 50, 800, 450)) on BGR data."""
    image_module = pytest.importorskip("PIL.Image")
    model = create_model(PINHOLE, rig=pinhole_rig)
    frames = Renderer().render(pinhole_rig, random_scene(np.random.default_rng(6)))
    images = np.stack([frames[n] for n in pinhole_rig.names])
    expected = np.stack(
        [np.asarray(image_module.fromarray(im, "RGB").resize((800, 450)).crop((0, 50, 800, 450))) for im in images]
    )
    with torch.no_grad():
        x = model.normalise(torch.from_numpy(images[None])).permute(0, 2, 3, 1).numpy()
    mean, std = np.array(model.config.image.mean, np.float32), np.array(model.config.image.std, np.float32)
    np.testing.assert_allclose(x, (expected.astype(np.float32) - mean) / std, rtol=0, atol=1e-5)


# -- synthetic frames in the dataset layout ------------------------------------------------------


def test_pinhole_frames_are_written_and_read_back(pinhole_rig: Rig, tmp_path: Path) -> None:
    """The layout stores no pinhole intrinsics: its reader takes the converter's 1280x720 90-degree pinhole,
    which rig-pinhole6's cameras are; no calib_results.txt is needed for them."""
    (written,) = synthesize(pinhole_rig, tmp_path, frames=1, seed=3)
    frame = Fisheye3DOD(tmp_path, "val", cameras=PINHOLE_CAMERAS)[0]
    assert not (tmp_path / "calib_results.txt").exists()
    assert frame.rig.names == list(PINHOLE_CAMERAS) and all(c.model == PINHOLE_MODEL for c in frame.rig.cameras)
    np.testing.assert_allclose(frame.rig.cam2lidar(), pinhole_rig.cam2lidar(), atol=1e-6)
    np.testing.assert_array_equal(frame.gt_boxes, written.boxes)
    assert frame.image("nu_rgb_camera_rear").shape == (720, 1280, 3)
    small = resized_rig(pinhole_rig, 0.125)  # scaled about pixel centres: cx = 79.5625, not W/2
    with pytest.raises(DatasetError, match="camera 'nu_rgb_camera_front': the layout stores no pinhole intrinsics"):
        synthesize(small, tmp_path / "small", frames=1)


def test_pinhole_frames_of_another_size_read_back_with_the_converters_pinhole_of_that_size(tmp_path: Path) -> None:
    """The compact pinhole baseline's rig: the converter's 90-degree pinhole at 512x288, which the reader
    rebuilds from the images' size."""
    from fisheye_infer.models.training.compact import compact_pinhole_rig

    rig = compact_pinhole_rig()
    synthesize(rig, tmp_path, frames=1, seed=3)
    frame = Fisheye3DOD(tmp_path, "val", cameras=PINHOLE_CAMERAS)[0]
    assert [c.model for c in frame.rig.cameras] == [c.model for c in rig.cameras]
    assert frame.rig.cameras[0].model.cx == 256.0 and frame.image("nu_rgb_camera_front").shape == (288, 512, 3)


# -- architecture from a checkpoint --------------------------------------------------------------


def test_the_config_tells_the_two_apart(tmp_path: Path) -> None:
    state_dict, _ = load_checkpoint(kit_checkpoint(PINHOLE, tmp_path / "kit.pth"))
    assert set(matching_architectures(state_dict)) == {PINHOLE, PERSP}  # same keys, an image-plane frustum
    assert infer_architecture(state_dict, DATA / "nusc_bevdet.py") == PINHOLE
    assert infer_architecture(state_dict, DATA / "fisheye_to_pinhole_bevdet.py") == PERSP
    with pytest.raises(Exception, match="pass --config"):
        infer_architecture(state_dict)
    with pytest.raises(Exception, match="fits none of them"):
        infer_architecture(state_dict, DATA / "fisheye_bevdet.py")
    petr, _ = load_checkpoint(kit_checkpoint(PINHOLE_PETR, tmp_path / "petr.pth"))
    assert set(matching_architectures(petr)) == {
        "fisheye-petr-cyl",
        PINHOLE_PETR,
        PERSP_PETR,
    }  # no stored table tells them apart
    for arch in (PINHOLE_PETR, PERSP_PETR):
        assert infer_architecture(petr, DATA / CONFIGS[arch]) == arch
    assert infer_architecture(petr, DATA / "fisheye_to_cyl_petr.py") == "fisheye-petr-cyl"


# -- the kit checkpoints, exported at full size ----------------------------------------------------


@pytest.fixture(scope="module", params=[PERSP, PINHOLE_PETR])
def kit_export(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory, pinhole_rig: Rig, rig: Rig):  # noqa: ANN201
    """A kit checkpoint exported at full size with its released config: one BEVDet and one PETR, one through each
    front end (the rectified fisheye images, the six pinhole images); the other two pairings are exported at full
    size by ``benchmarks/official_configs.py``, and at reduced size by ``tests/models/test_models.py``."""
    arch = request.param
    folder = tmp_path_factory.mktemp(arch)
    config = DATA / CONFIGS[arch]
    the_rig = pinhole_rig if arch.startswith("pinhole") else rig
    result = export(
        kit_checkpoint(arch, folder / "kit.pth"),
        folder / "kit.onnx",
        config=config,
        rig=the_rig,
        frames=1,
        progress=lambda _: None,
    )
    return arch, result, the_rig


@pytest.mark.slow
def test_kit_checkpoint_exports_with_a_passing_self_check(kit_export) -> None:  # noqa: ANN001
    arch, result, the_rig = kit_export
    assert result.parity.passed and result.parity.threads == (1, 2)
    meta = read_meta(result.path)
    assert meta.architecture == arch and meta.cameras == tuple(the_rig.names)
    assert meta.geometry_source == (
        "checkpoint" if arch.endswith("bevdet") or arch == PERSP else "rig"
    )  # PETR stores no table
    assert meta.image_size == ((1280, 720) if arch.startswith("pinhole") else (800, 800))
    assert meta.tensorrt.compatible


@pytest.mark.slow
def test_eval_runs_the_baseline_on_frames_of_its_rig(kit_export, tmp_path: Path) -> None:  # noqa: ANN001
    """``fisheye-infer eval`` reads the cameras from the file: six pinhole images or four fisheye ones per frame."""
    arch, result, the_rig = kit_export
    (written,) = synthesize(the_rig, tmp_path, frames=1, seed=4)
    detector = Detector(result.path, threads=2)
    dataset = Fisheye3DOD(tmp_path, "val", cameras=list(detector.info.cameras))
    gt, pred = detect_dataset(detector, dataset, progress=False)
    records = pred[written.token]
    assert list(pred) == [written.token] and 0 < len(records) <= result.meta.num_boxes  # the valid boxes, unthresholded
    report = evaluate_results(gt, pred)
    assert report.to_markdown().startswith("#")


@pytest.mark.slow
def test_rebake_recomputes_the_baseline_tables(kit_export, tmp_path: Path) -> None:  # noqa: ANN001
    arch, result, the_rig = kit_export
    data = the_rig.model_dump(mode="json")
    for cam in data["cameras"]:
        cam["cam2lidar"][0][3] += 0.3  # every camera 0.3 m further forward
    moved = Rig.from_dict(data)
    meta = rebake(result.path, moved, tmp_path / "moved.onnx", mode="tables")
    assert meta.rig_hash == moved.hash and meta.geometry == read_meta(result.path).geometry
    with pytest.raises(RigError):
        rebake(
            result.path,
            default_rig() if arch.startswith("pinhole") else resolve_rig(PINHOLE_RIG),
            tmp_path / "wrong.onnx",
        )
