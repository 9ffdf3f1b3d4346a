"""The cylindrical baselines, fisheye-bevdet-cyl and fisheye-petr-cyl: the image rectification against
cv2.remap, the released degrees-as-radians geometry, PETR's swapped unpacking, checkpoints and tables.

Most tests use reduced configurations (48 x 96 cylinders); each model runs one full-size forward.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
import onnx
import pytest
import torch
import torch.nn.functional as F
from small_configs import SMALL_BEV_SECTIONS  # noqa: E402

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import CheckpointError, ConfigError
from fisheye_infer.geometry.cyl_lss import CylLSSParams, cyl_image_grid
from fisheye_infer.geometry.cyl_petr import CylPETRParams, cyl_petr_directions
from fisheye_infer.geometry.grids import (
    cylindrical_directions,
    cylindrical_remap,
    invalid_mask,
    remap_grid,
    remap_taps,
)
from fisheye_infer.geometry.kinds import tables_for
from fisheye_infer.geometry.petr import lid_depths, position_coords
from fisheye_infer.geometry.tables import DEFAULT_BUCKET_SIZES
from fisheye_infer.models import create_model, get_model_entry, list_models, load_model, make_checkpoint
from fisheye_infer.models.cyl_config import BEVDetCylConfig, CylPETRConfig, CylViewTransformConfig
from fisheye_infer.models.fisheye_bevdet_cyl import FRUSTUM_ATOL, GEOMETRY_KEYS
from fisheye_infer.models.seeded_checkpoint import manifest_specs
from fisheye_infer.scenes.render import Renderer, random_scene

DATA = Path(__file__).parent / "data"
BEVDET, PETR = "fisheye-bevdet-cyl", "fisheye-petr-cyl"
TAN45 = 1.6197752  # tan(45 rad): the released vertical range taken as radians
CORRECTED = {
    "azimuth_range": (-math.radians(110), math.radians(110)),
    "elevation_range": (-math.radians(45), math.radians(45)),
}

SMALL_BEVDET = BEVDetCylConfig().replace(
    cylinder={"height": 48, "width": 96},
    **dict(SMALL_BEV_SECTIONS, view_transform={**SMALL_BEV_SECTIONS["view_transform"], "feature_size": (3, 6)}),
)
SMALL_PETR = CylPETRConfig().replace(
    cylinder={"height": 48, "width": 96},
    head={
        "feature_size": (3, 6),
        "num_query": 40,
        "max_num": 30,
        "embed_dims": 64,
        "num_heads": 4,
        "ffn_dims": 128,
        "num_layers": 2,
    },
)


def _images(seed: int, batch: int = 1) -> torch.Tensor:
    gen = torch.Generator().manual_seed(seed)
    return torch.randint(0, 256, (batch, 4, 800, 800, 3), generator=gen, dtype=torch.uint8)


def _run(model: torch.nn.Module, images: torch.Tensor, **kw: object) -> dict[str, torch.Tensor]:
    with torch.no_grad():
        return model(images, **kw)


def _moved_rig(rig: Rig, dx: float) -> Rig:
    """The same cameras, every one moved ``dx`` metres forward: other pooling tables, other bucket sizes."""
    shift = np.zeros((4, 4))
    shift[0, 3] = dx
    return Rig.from_cameras(
        {c.name: c.model for c in rig.cameras},
        {c.name: c.matrix + shift for c in rig.cameras},
        order=rig.names,
        name="moved",
    )


@pytest.fixture(scope="module")
def full_bevdet() -> torch.nn.Module:
    return create_model(BEVDET)


@pytest.fixture(scope="module")
def full_petr() -> torch.nn.Module:
    return create_model(PETR)


@pytest.fixture(scope="module")
def small_ckpts() -> dict[str, dict[str, torch.Tensor]]:
    return {
        BEVDET: make_checkpoint(BEVDET, 1, config=SMALL_BEVDET)["state_dict"],
        PETR: make_checkpoint(PETR, 1, config=SMALL_PETR)["state_dict"],
    }


@pytest.fixture(scope="module")
def small_models(small_ckpts) -> dict[str, torch.nn.Module]:  # noqa: ANN001
    return {
        BEVDET: load_model(BEVDET, small_ckpts[BEVDET], config=SMALL_BEVDET)[0],
        PETR: load_model(PETR, small_ckpts[PETR], config=SMALL_PETR)[0],
    }


@pytest.fixture(scope="module")
def fisheye_frame(rig: Rig) -> np.ndarray:
    """An 800 x 800 rendered fisheye picture: sharp box edges, checker ground, black beyond the lens."""
    return Renderer().render_camera(rig.cameras[0], random_scene(np.random.default_rng(3)))


# -- the image rectification against cv2.remap -------------------------------------------------


@pytest.mark.parametrize("ranges", ["released", "corrected"])
def test_remap_grid_reproduces_cv2_remap(rig: Rig, fisheye_frame: np.ndarray, ranges: str) -> None:
    """cv2 (OpenCV 4.x) remaps float maps in 1/32 px fixed point; convertMaps(CV_16SC2) gives those maps.

    The graph's taps (``remap_taps``) give cv2's result to the bit; GridSample with the same grid
    (PyTorch's weights) misses it by a hundredth of a grey level, and the unrounded maps by several.
    """
    az, el = ((-110.0, 110.0), (-45.0, 45.0)) if ranges == "released" else CORRECTED.values()
    heights = (math.tan(el[0]), math.tan(el[1]))
    camera = rig.shared_model()
    map_x, map_y = cylindrical_remap(camera, (400, 800), az, heights)
    fixed = cv2.convertMaps(map_x, map_y, cv2.CV_16SC2)
    image = fisheye_frame.astype(np.float32)
    reference = cv2.remap(image, *fixed, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0)

    def sample(grid: np.ndarray) -> np.ndarray:
        x = torch.from_numpy(image).permute(2, 0, 1)[None]
        out = F.grid_sample(x, torch.from_numpy(grid)[None], mode="bilinear", padding_mode="zeros", align_corners=True)
        return out[0].permute(1, 2, 0).numpy()

    grid = cyl_image_grid(
        rig,
        CylLSSParams(
            feature_size=(25, 50),
            azimuth_range=az,
            elevation_range=el,
            image_size=(400, 800),
            dbound=(0.5, 48.5, 0.5),
            xbound=(-48, 48, 0.3),
            ybound=(-48, 48, 0.3),
            zbound=(-5, 5, 10),
        ),
    )
    assert grid.shape == (4, 400, 800, 2) and all(np.array_equal(g, grid[0]) for g in grid)  # one lens
    taps = remap_taps(grid[0], 800, 800)
    rows = image.reshape(-1, 3)
    ours = np.einsum("pk,pkc->pc", taps.weight[:, 0], rows[taps.index.reshape(-1, 4)]).reshape(400, 800, 3)
    np.testing.assert_array_equal(ours, reference)
    assert 0 < np.abs(sample(grid[0]) - reference).max() < 0.05
    assert black_share(reference) > (0.3 if ranges == "released" else 0.0)  # released: rays behind the lens
    # Without the 1/32 px rounding the same maps miss cv2 by several grey levels at sharp edges.
    unrounded = np.stack([2 * map_x / 799.0 - 1, 2 * map_y / 799.0 - 1], axis=-1).astype(np.float32)
    assert np.abs(sample(unrounded) - reference).max() > 2.0


def black_share(image: np.ndarray) -> float:
    return float((image == 0).all(axis=-1).mean())


def test_remap_grid_rounding_and_border_by_hand() -> None:
    w = h = 8
    mx = np.array([[3.015625, 3.046875, 3.02, -1.0, -0.5, 7.5, 8.0]], np.float32)  # 3 + 1/64 is a tie: to even
    grid = remap_grid(mx, np.full_like(mx, 2.0), w, h)
    u = (grid[..., 0].astype(np.float64) + 1) * (w - 1) / 2
    np.testing.assert_allclose(u[0], [3.0, 3.0625, 3.03125, -2.0, -0.5, 7.5, -2.0], atol=1e-5)
    np.testing.assert_allclose(grid[0, 4, 1], 2 * 2.0 / (h - 1) - 1, atol=1e-7)  # align_corners=True normalisation
    with pytest.raises(ConfigError, match="map_x, map_y"):
        remap_grid(mx, mx[:, :3], w, h)


def test_model_rectifies_before_normalising(small_models, rig: Rig, fisheye_frame: np.ndarray) -> None:  # noqa: ANN001
    model = small_models[BEVDET]
    camera = rig.shared_model()
    vt = SMALL_BEVDET.view_transform
    map_x, map_y = cylindrical_remap(
        camera, (48, 96), vt.azimuth_range, (math.tan(vt.elevation_range[0]), math.tan(vt.elevation_range[1]))
    )
    raw = cv2.remap(
        fisheye_frame.astype(np.float32),
        *cv2.convertMaps(map_x, map_y, cv2.CV_16SC2),
        cv2.INTER_LINEAR,
        borderMode=cv2.BORDER_CONSTANT,
    )
    mean, std = np.array(SMALL_BEVDET.image.mean, np.float32), np.array(SMALL_BEVDET.image.std, np.float32)
    frames = torch.from_numpy(np.broadcast_to(fisheye_frame, (1, 4, 800, 800, 3)).copy())
    with torch.no_grad():
        x = model.normalise(frames)[0].permute(1, 2, 0).numpy()  # camera 0, Hc x Wc x 3
    np.testing.assert_allclose(x, (raw - mean) / std, rtol=0, atol=1e-5)  # cv2's pixels, normalised
    black = (raw == 0).all(axis=-1)
    assert black.any()
    np.testing.assert_allclose(x[black], np.broadcast_to(-mean / std, x[black].shape), rtol=1e-6)


def test_rectification_is_per_sample_and_gathers_channel_planes(small_exports, rig: Rig) -> None:  # noqa: ANN001
    """``rectify`` on a batch of two frames is each frame's alone; the exported graph gathers its taps from one plane
    per channel (GatherElements) and never multiplies the weights in a per-pixel MatMul."""
    from fisheye_infer.geometry.tables import RECTIFY, camera_taps, taps_index, taps_weight
    from fisheye_infer.models.cylindrical import rectify

    rng = np.random.default_rng(5)
    grids = np.stack([rng.uniform(-1.1, 1.1, (6, 8, 2)) for _ in range(2)])
    taps = camera_taps(grids, 10, 12, prefix=RECTIFY)
    index, weight = torch.from_numpy(taps.index), torch.from_numpy(taps.weight)
    frames = torch.from_numpy(rng.integers(0, 256, (2, 2, 10, 12, 3), dtype=np.uint8))
    both = rectify(frames, index, weight, (6, 8))
    assert both.shape == (2, 2, 3, 6, 8)
    for b in range(2):
        torch.testing.assert_close(both[b : b + 1], rectify(frames[b : b + 1], index, weight, (6, 8)), rtol=0, atol=0)
    graph = onnx.load(small_exports(BEVDET).onnx).graph
    readers = [node.op_type for node in graph.node if taps_weight(RECTIFY) in node.input]
    assert readers and "MatMul" not in readers
    values, gathers = {taps_index(RECTIFY)}, []  # the index table's way to the gathers that use it
    for node in graph.node:
        if node.op_type == "GatherElements" and node.input[1] in values:
            gathers.append(node.input[0])
        elif values.intersection(node.input):
            assert node.op_type != "Gather", "the taps gathered as rows of three values"
            values.update(node.output)
    assert len(set(gathers)) == 3  # one channel plane each


# -- the released geometry: degrees used as radians --------------------------------------------


def test_released_configs_are_read_as_written() -> None:
    bevdet = BEVDetCylConfig.from_mmdet3d_config(DATA / "fisheye_to_cyl_bevdet.py")
    petr = CylPETRConfig.from_mmdet3d_config(DATA / "fisheye_to_cyl_petr.py")
    assert bevdet == BEVDetCylConfig() and petr == CylPETRConfig()
    assert bevdet.view_transform.azimuth_range == petr.head.azimuth_range == (-110.0, 110.0)
    assert bevdet.view_transform.elevation_range == petr.head.elevation_range == (-45.0, 45.0)
    assert bevdet.cylinder == petr.cylinder and (petr.cylinder.height, petr.cylinder.width) == (400, 800)
    assert bevdet.view_transform.feature_size == petr.head.feature_size == (25, 50)
    assert BEVDetCylConfig.from_dict(bevdet.to_dict()) == bevdet
    assert CylPETRConfig.from_dict(petr.to_dict()) == petr


@pytest.mark.parametrize(
    "name, reader", [("fisheye_to_cyl_bevdet.py", BEVDetCylConfig), ("fisheye_to_cyl_petr.py", CylPETRConfig)]
)
def test_radians_in_the_config_give_the_corrected_geometry(tmp_path: Path, name: str, reader: type) -> None:
    text = (DATA / name).read_text()
    fixed = (
        text.replace("[-110, 110]", "[-math.radians(110), math.radians(110)]")
        .replace("(-110, 110)", "(-math.radians(110), math.radians(110))")
        .replace("[-45, 45]", "[-math.radians(45), math.radians(45)]")
        .replace("(-45, 45)", "(-math.radians(45), math.radians(45))")
    )
    (tmp_path / name).write_text("import math\n" + fixed)
    cfg = reader.from_mmdet3d_config(tmp_path / name)
    section = cfg.view_transform if reader is BEVDetCylConfig else cfg.head
    assert section.azimuth_range == pytest.approx(CORRECTED["azimuth_range"])
    assert section.elevation_range == pytest.approx(CORRECTED["elevation_range"])
    # Only the model's copy corrected: images and rays would disagree, which is refused.
    model_only = (
        text.replace("vertical_range=[-45, 45]),\n    pts_backbone", "vertical_range=[-0.7, 0.7]),\n    pts_backbone")
        if reader is BEVDetCylConfig
        else text.replace("vertical_range=(-45, 45)", "vertical_range=(-0.7, 0.7)")
    )
    assert model_only != text
    (tmp_path / name).write_text(model_only)
    with pytest.raises(ConfigError, match="vertical_range"):
        reader.from_mmdet3d_config(tmp_path / name)


def test_released_image_grid_steps_radians_per_column(rig: Rig, full_bevdet) -> None:  # noqa: ANN001
    """0.2753 rad per output column of the 800-wide image and heights +-tan(45 rad) = +-1.6197752."""
    params = full_bevdet.geometry_params()
    assert params.image_size == (400, 800)
    assert params.height_range == pytest.approx((-TAN45, TAN45), abs=1e-7)
    assert pytest.approx(0.2753, abs=1e-4) == 220.0 / 799
    assert math.tan(45.0) == pytest.approx(TAN45, abs=1e-7)
    phi = -110.0 + np.arange(800) * (220.0 / 799)
    y = -math.tan(45.0) + np.arange(400) * (2 * math.tan(45.0) / 399)
    rays = np.stack(np.broadcast_arrays(np.sin(phi)[None], y[:, None], np.cos(phi)[None]), axis=-1)
    camera = rig.shared_model()
    uv = camera.world2cam(rays.reshape(-1, 3)).reshape(400, 800, 2).astype(np.float32)
    expected = remap_grid(uv[..., 0], uv[..., 1], camera.width, camera.height)
    grid = full_bevdet.view_transform.geometry.image_grid  # each camera's: one lens
    one_step = 2.0 / (camera.width - 1) / 32  # an ulp of difference may tip a 1/32 px rounding
    np.testing.assert_allclose(grid, np.broadcast_to(expected, grid.shape), rtol=0, atol=1.01 * one_step)


def test_released_images_black_cells_are_outside_the_lens(rig: Rig, full_bevdet) -> None:  # noqa: ANN001
    """The released cylinder's rays past the lens leave a quarter of its stride-16 cells mostly black: those are the
    cells without a depth target (``inside_lens``), each the mean of its 16 x 16 pixels' lens validity."""
    g = full_bevdet.view_transform.geometry
    valid = 1.0 - invalid_mask(rig.shared_model(), g.image_grid[0])  # 400 x 800
    blocks = valid.reshape(25, 16, 50, 16).mean(axis=(1, 3))
    np.testing.assert_array_equal(g.inside_lens, np.broadcast_to(blocks > 0.5, (4, 25, 50)))  # four cameras, one lens
    assert 0.2 < 1.0 - g.inside_lens.mean() < 0.3


def test_released_frustum(full_bevdet) -> None:  # noqa: ANN001
    """The frustum takes the same numbers: phi = linspace(-110, 110, 50) rad, y = linspace(-tan 45, tan 45, 25)."""
    frustum = full_bevdet.view_transform.geometry.frustum
    assert frustum.shape == (96, 25, 50, 3)
    d = np.linspace(0.5, 48.5, 96)
    np.testing.assert_allclose(
        np.hypot(frustum[..., 0], frustum[..., 2]), np.broadcast_to(d[:, None, None], (96, 25, 50)), rtol=1e-6
    )
    np.testing.assert_allclose(frustum[:, 0, :, 1] / d[:, None], -TAN45, rtol=1e-6)
    phi = np.arctan2(frustum[1, 0, :, 0], frustum[1, 0, :, 2])
    np.testing.assert_allclose(np.remainder(phi - np.linspace(-110, 110, 50) + np.pi, 2 * np.pi) - np.pi, 0, atol=1e-5)
    corrected = full_bevdet.geometry_params().model_copy(update=CORRECTED).frustum()
    assert np.abs(corrected - frustum).max() > 10.0  # metres: the two geometries are far apart


def test_official_float32_frustum_is_within_tolerance(full_bevdet) -> None:  # noqa: ANN001
    """The official frustum is torch float32 arithmetic on +-110 rad: 'verify' must accept it, with margin."""
    ds = torch.linspace(0.5, 48.5, 96).view(96, 1, 1)
    phi, y = torch.meshgrid(
        torch.linspace(-110, 110, 50), torch.linspace(math.tan(-45), math.tan(45), 25), indexing="xy"
    )
    official = torch.stack([ds * torch.sin(phi), ds * y, ds * torch.cos(phi)], dim=-1).numpy()
    diff = np.abs(official - full_bevdet.view_transform.geometry.frustum).max()
    assert 0 < diff < FRUSTUM_ATOL / 4


# -- PETR: swapped unpacking and no mask --------------------------------------------------------


def test_petr_rays_are_unpacked_swapped(full_petr) -> None:  # noqa: ANN001
    params = full_petr.geometry_params()
    assert isinstance(params, CylPETRParams) and params.feature_size == (25, 50)
    rays = cyl_petr_directions(params)  # H x W x 3
    np.testing.assert_allclose(rays[0, 0], [math.sin(110.0), TAN45, math.cos(110.0)], atol=1e-6)
    np.testing.assert_allclose(rays[-1, -1], [math.sin(-110.0), -TAN45, math.cos(-110.0)], atol=1e-6)
    h_max, h_min = params.azimuth_range  # the official head's unpacking, then linspace(min, max)
    v_max, v_min = params.elevation_range
    phi, y = np.meshgrid(np.linspace(h_min, h_max, 50), np.linspace(math.tan(v_min), math.tan(v_max), 25))
    np.testing.assert_allclose(rays, np.stack([np.sin(phi), y, np.cos(phi)], axis=-1), atol=1e-12)
    # both axes reversed with respect to the image (a half turn about the optical axis)
    image_order = cylindrical_directions((25, 50), params.azimuth_range, params.height_range)
    np.testing.assert_allclose(rays, image_order[::-1, ::-1], atol=1e-9)
    # the head's position-encoder input is built on the swapped rays, not on the image's
    coords = full_petr.pts_bbox_head.coords3d.numpy()
    depths = lid_depths(params.depth_num, params.depth_start, params.position_range[3])
    cam2lidar = full_petr.pts_bbox_head.geometry.cam2lidar
    swapped = position_coords(cam2lidar, (25, 50), depths=depths, position_range=params.position_range, directions=rays)
    unswapped = position_coords(
        cam2lidar, (25, 50), depths=depths, position_range=params.position_range, directions=image_order
    )
    np.testing.assert_array_equal(coords, swapped)
    assert np.abs(coords - unswapped).max() > 1.0


def test_petr_masks_nothing(full_petr) -> None:  # noqa: ANN001
    tables = full_petr.geometry_tables()
    assert not tables["geom.petr.key_mask"].any()
    assert not full_petr.pts_bbox_head.key_mask().any()


# -- checkpoints --------------------------------------------------------------------------------


@pytest.mark.parametrize("arch, count", [(BEVDET, 306), (PETR, 350)])
def test_official_keys_match_manifest(arch: str, count: int, full_bevdet, full_petr) -> None:  # noqa: ANN001
    model = full_bevdet if arch == BEVDET else full_petr
    assert arch in list_models()
    specs = manifest_specs(arch)
    keys = model.official_keys()
    assert list(keys) == list(specs) and len(keys) == count
    for key, spec in specs.items():
        assert keys[key] == spec, key
    geometry = set(GEOMETRY_KEYS) if arch == BEVDET else set()
    assert set(model.state_dict()) == set(keys) - geometry
    if arch == BEVDET:
        assert specs["view_transform.frustum"][0] == (96, 25, 50, 3)


@pytest.mark.parametrize("arch", [BEVDET, PETR])
def test_strict_load_of_synthetic_checkpoint(arch: str, small_ckpts, small_models) -> None:  # noqa: ANN001
    sd, model = small_ckpts[arch], small_models[arch]
    weights = model.state_dict()
    for key, value in get_model_entry(arch).checkpoint_filter(sd).items():
        assert torch.equal(weights[key], value), key
    config = SMALL_BEVDET if arch == BEVDET else SMALL_PETR
    _, report = load_model(arch, sd, config=config)
    assert report.source == ("checkpoint" if arch == BEVDET else "rig") and all(c.agrees for c in report.checks)


@pytest.mark.parametrize(
    "arch, key, kind",
    [
        (BEVDET, "view_transform.frustum", "missing"),
        (BEVDET, "bbox_head.shared_conv.bias", "missing"),
        (BEVDET, "view_transform.sphere_grid_2d", "unexpected"),  # a fisheye geometry key
        (PETR, "pts_bbox_head.query_embedding.0.weight", "missing"),
        (PETR, "pts_bbox_head.unvalid_area", "unexpected"),
    ],
)
def test_bad_key_is_named(arch: str, key: str, kind: str, small_ckpts) -> None:  # noqa: ANN001
    sd = dict(small_ckpts[arch])
    if kind == "missing":
        del sd[key]
    else:
        sd[key] = torch.zeros(3)
    with pytest.raises(CheckpointError, match=rf"1 {kind} keys[\s\S]*{key.replace('.', '[.]')}"):
        load_model(arch, sd, config=SMALL_BEVDET if arch == BEVDET else SMALL_PETR)


def test_frustum_policy(small_ckpts) -> None:  # noqa: ANN001
    """The stored frustum records the ranges the checkpoint was trained with."""
    sd = dict(small_ckpts[BEVDET])
    corrected = SMALL_BEVDET.replace(view_transform=CORRECTED)
    with pytest.raises(CheckpointError, match="view_transform.frustum"):
        load_model(BEVDET, sd, config=corrected)
    with pytest.warns(UserWarning, match="view_transform.frustum"):
        model, report = load_model(BEVDET, sd, config=corrected, geometry="rig")
    assert report.source == "rig"
    sd["view_transform.frustum"] = sd["view_transform.frustum"] * 1.001
    with pytest.warns(UserWarning):
        model, report = load_model(BEVDET, sd, config=SMALL_BEVDET, geometry="checkpoint")
    assert report.source == "checkpoint"
    np.testing.assert_array_equal(model.view_transform.geometry.frustum, sd["view_transform.frustum"].numpy())
    sd["view_transform.nx"] = torch.tensor([10, 10, 1])
    with pytest.raises(CheckpointError, match="view_transform.nx"):
        load_model(BEVDET, sd, config=SMALL_BEVDET, geometry="checkpoint")


# -- forward and tables -------------------------------------------------------------------------


@pytest.mark.parametrize("arch, boxes", [(BEVDET, 200), (PETR, 300)])
def test_full_size_forward(arch: str, boxes: int, full_bevdet, full_petr) -> None:  # noqa: ANN001
    model = full_bevdet if arch == BEVDET else full_petr
    out = _run(model, _images(0))
    assert out["boxes"].shape == (1, boxes, 7) and out["scores"].shape == (1, boxes)
    assert out["labels"].dtype == torch.int64 and out["valid"].dtype == torch.bool
    assert torch.isfinite(out["boxes"]).all() and torch.isfinite(out["scores"]).all()


def test_geometry_table_names(full_bevdet, full_petr) -> None:  # noqa: ANN001
    lss = full_bevdet.geometry_tables()
    buckets = len(DEFAULT_BUCKET_SIZES)
    assert set(lss) == {"geom.rectify.index", "geom.rectify.weight", "geom.pool.counts", "geom.pool.cell_rows"} | {
        f"geom.pool.{kind}.{b}" for kind in ("points", "pixels") for b in range(buckets)
    }
    assert lss["geom.rectify.index"].shape == (4 * 400 * 800 * 4,)  # four taps per pixel of each camera
    assert lss["geom.rectify.weight"].shape == (4 * 400 * 800, 1, 4)
    assert [lss[f"geom.pool.points.{b}"].shape[1] for b in range(buckets)] == list(DEFAULT_BUCKET_SIZES)
    petr = full_petr.geometry_tables()
    assert {k: tuple(v.shape) for k, v in petr.items()} == {
        "geom.rectify.index": (4 * 400 * 800 * 4,),
        "geom.rectify.weight": (4 * 400 * 800, 1, 4),
        "geom.petr.key_pos": (1, 5000, 256),
        "geom.petr.key_mask": (1, 5000),
    }
    assert petr["geom.petr.key_mask"].dtype == torch.bool


@pytest.mark.parametrize("arch", [BEVDET, PETR])
def test_tables_are_those_of_the_numpy_definition(arch: str, small_models, rig: Rig) -> None:  # noqa: ANN001
    model = small_models[arch]
    expected = tables_for(rig, model.geometry_params(), model.table_weights())
    tables = model.geometry_tables()
    assert set(tables) == set(expected)
    for name, value in expected.items():
        np.testing.assert_allclose(tables[name].numpy(), value, rtol=1e-6, atol=1e-6, err_msg=name)


@pytest.mark.parametrize("arch", [BEVDET, PETR])
def test_forward_takes_every_table_from_the_dict(arch: str, small_models) -> None:  # noqa: ANN001
    model = small_models[arch]
    images = _images(1)
    base = _run(model, images)
    same = _run(model, images, tables=model.geometry_tables())
    for key in base:
        assert torch.equal(base[key], same[key]), key
    flipped = dict(model.geometry_tables())
    flipped["geom.rectify.index"] = flipped["geom.rectify.index"].flip(0)
    assert not torch.equal(_run(model, images, tables=flipped)["scores"], base["scores"])
    if arch == PETR:  # the pooling tables are exercised by the next test
        moved = dict(model.geometry_tables())
        moved["geom.petr.key_pos"] = moved["geom.petr.key_pos"].roll(1, dims=1)
        assert not torch.equal(_run(model, images, tables=moved)["scores"], base["scores"])


def test_tables_of_another_rig_with_other_bucket_sizes(small_models, rig: Rig) -> None:  # noqa: ANN001
    """K_b comes from the tables' shapes: one model runs another rig's tables like a model built for it."""
    model = small_models[BEVDET]
    other_rig = _moved_rig(rig, 0.9)
    other = create_model(BEVDET, SMALL_BEVDET, other_rig)
    other.load_state_dict(model.state_dict())
    tables = {k: torch.from_numpy(v) for k, v in tables_for(other_rig, model.geometry_params()).items()}
    ours = model.geometry_tables()
    assert any(tables[k].shape != ours[k].shape for k in ours if k.startswith("geom.pool.points."))
    images = _images(2)
    a, b = _run(model, images, tables=tables), _run(other, images)
    torch.testing.assert_close(a["scores"], b["scores"])
    torch.testing.assert_close(a["boxes"], b["boxes"])


# -- configuration ------------------------------------------------------------------------------


def test_inconsistent_configurations_are_refused() -> None:
    with pytest.raises(ConfigError, match="view_transform.feature_size"):
        BEVDetCylConfig().replace(cylinder={"height": 200})
    with pytest.raises(ConfigError, match="cylinder.height/width"):
        CylPETRConfig().replace(cylinder={"height": 200})
    with pytest.raises(ConfigError, match="elevation_range"):
        CylPETRConfig().replace(head={"elevation_range": (0.3, 0.3)})
    with pytest.raises(ConfigError, match="image.height/width"):
        create_model(BEVDET, BEVDetCylConfig().replace(image={"height": 640, "width": 640}))
    with pytest.raises(ConfigError, match="CylindricalLSSTransform"):
        BEVDetCylConfig.from_mmdet3d_config(DATA / "fisheye_bevdet.py")
    with pytest.raises(ConfigError, match="needs a BEVDetCylConfig"):
        create_model(BEVDET, config=CylPETRConfig())
    assert CylViewTransformConfig(dbound=(0.5, 48.5, 0.7)).num_depth_bins == 68  # int(), as the official code
