"""FisheyeBEVDet: strict checkpoint loading, geometry policy, forward pass and the official quirks."""

from __future__ import annotations

import argparse
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.errors import CheckpointError, ConfigError, FrameError
from fisheye_infer.geometry import (
    BevGrid,
    build_pooling_plan,
    frustum_to_lidar,
    pool_bev_reference,
    spherical_directions,
)
from fisheye_infer.geometry.lss import LSSGeometry, LSSParams
from fisheye_infer.models import (
    BEVDetConfig,
    create_model,
    list_models,
    load_checkpoint,
    load_model,
    make_checkpoint,
    read_mmdet3d_config,
)
from fisheye_infer.models.bevdet_config import ViewTransformConfig
from fisheye_infer.models.fisheye_bevdet import GEOMETRY_KEYS, checkpoint_filter_fn
from fisheye_infer.models.seeded_checkpoint import init_weights, manifest_specs, synthetic_images
from fisheye_infer.models.transfusion import TransFusionDecoderLayer, TransFusionHead
from fisheye_infer.models.view_transform import FisheyeLSS

DATA = Path(__file__).parent / "data"

VT = "view_transform."


# -- manifest and strict loading ---------------------------------------------------------------


def test_official_keys_match_manifest() -> None:
    model = create_model("fisheye-bevdet")
    keys = model.official_keys()
    specs = manifest_specs("fisheye-bevdet")
    assert list(keys) == list(specs)  # same keys, same (checkpoint) order
    assert len(keys) == 309
    for key, (shape, dtype) in specs.items():
        assert keys[key] == (shape, dtype), key


def test_registry() -> None:
    assert "fisheye-bevdet" in list_models()
    with pytest.raises(ConfigError, match="unknown model 'nope'"):
        create_model("nope")
    with pytest.raises(ConfigError, match="BEVDetConfig"):
        create_model("fisheye-bevdet", config=object())


def test_strict_load_full_synthetic(full_checkpoint: dict, full_model) -> None:
    model, report = full_model
    assert report.source == "checkpoint"
    assert all(c.agrees for c in report.checks)
    sd = full_checkpoint["state_dict"]
    assert torch.equal(model.bbox_head.shared_conv.weight, sd["bbox_head.shared_conv.weight"])
    assert all(torch.equal(torch.from_numpy(g), sd[VT + "sphere_grid_2d"]) for g in model.view_transform.geometry.grid)


def test_missing_unexpected_and_misshaped_keys_are_all_named(small_config, small_state_dict) -> None:
    sd = small_state_dict
    del sd["bbox_head.shared_conv.bias"]
    del sd[VT + "frustum"]
    sd["bbox_head.extra_conv.weight"] = torch.zeros(3)
    sd[VT + "depthnet.bias"] = torch.zeros(5)
    with pytest.raises(CheckpointError) as err:
        load_model("fisheye-bevdet", sd, config=small_config)
    msg = str(err.value)
    for part in (
        "bbox_head.shared_conv.bias",
        VT + "frustum",
        "bbox_head.extra_conv.weight",
        VT + "depthnet.bias: checkpoint [5], model [56]",
        "2 missing keys",
        "1 unexpected keys",
    ):
        assert part in msg


@pytest.mark.parametrize("edit", ["missing", "extra", "shape", "dtype"])
def test_single_key_problem_is_named(small_config, small_state_dict, edit: str) -> None:
    key = "pts_neck.deblocks.1.0.weight"
    sd = small_state_dict
    if edit == "missing":
        del sd[key]
    elif edit == "extra":
        key = "pts_neck.deblocks.2.0.weight"
        sd[key] = torch.zeros(1)
    elif edit == "shape":
        sd[key] = sd[key].transpose(0, 1).contiguous()[:, :-1]
    else:
        key = VT + "nx"
        sd[key] = sd[key].float()
    with pytest.raises(CheckpointError, match=key.replace(".", r"\.")):
        load_model("fisheye-bevdet", sd, config=small_config)


def test_reduced_model_loads_matching_checkpoint(small_config, small_checkpoint) -> None:
    model, report = load_model("fisheye-bevdet", small_checkpoint, config=small_config)
    assert report.source == "checkpoint"
    assert model.view_transform.depthnet.weight.shape == (24 + 32, 256, 1, 1)
    assert small_checkpoint["state_dict"][VT + "frustum"].shape == (24, 8, 32, 3)
    assert model.view_transform.geometry.plan.grid_xy == (80, 80) and model.bbox_head.bev_pos.shape == (1, 1600, 2)


def test_other_widths_do_not_load_into_official_model(small_checkpoint) -> None:
    with pytest.raises(CheckpointError) as err:
        load_model("fisheye-bevdet", small_checkpoint)
    assert "view_transform.depthnet.weight: checkpoint [56, 256, 1, 1], model [192, 256, 1, 1]" in str(err.value)
    assert "bbox_head.shared_conv.weight" in str(err.value)


def test_uncertain_proj_x_keys_are_ignored_with_warning(small_config, small_state_dict) -> None:
    small_state_dict[VT + "proj_x.weight"] = torch.zeros(32, 256, 1, 1)
    small_state_dict[VT + "proj_x.bias"] = torch.zeros(32)
    with pytest.warns(UserWarning, match="proj_x"):
        load_model("fisheye-bevdet", small_state_dict, config=small_config)


def test_checkpoint_filter_fn_is_identity_on_weights(small_checkpoint) -> None:
    sd = small_checkpoint["state_dict"]
    weights = checkpoint_filter_fn(sd)
    assert set(sd) - set(weights) == set(GEOMETRY_KEYS)
    assert all(weights[k] is sd[k] for k in weights)


# -- geometry policy ----------------------------------------------------------------------------


def test_geometry_mismatch_raises_unless_policy_given(small_config, small_state_dict) -> None:
    stored = small_state_dict[VT + "sphere_grid_2d"] + 1e-3
    small_state_dict[VT + "sphere_grid_2d"] = stored
    with pytest.raises(CheckpointError, match=r"(?s)rig.*differs.*sphere_grid_2d.*geometry='checkpoint'"):
        load_model("fisheye-bevdet", small_state_dict, config=small_config)
    with pytest.warns(UserWarning, match="sphere_grid_2d"):
        model, report = load_model("fisheye-bevdet", small_state_dict, config=small_config, geometry="checkpoint")
    assert report.source == "checkpoint"
    assert all(torch.equal(torch.from_numpy(g), stored) for g in model.view_transform.geometry.grid)
    with pytest.warns(UserWarning, match="recomputed"):
        model, report = load_model("fisheye-bevdet", small_state_dict, config=small_config, geometry="rig")
    assert report.source == "rig"
    assert np.array_equal(model.view_transform.geometry.grid, model.rig_geometry.grid)
    with pytest.raises(CheckpointError, match="not a geometry policy"):
        load_model("fisheye-bevdet", small_state_dict, config=small_config, geometry="ignore")


def test_geometry_within_rounding_uses_stored_tables_exactly(small_config, small_state_dict) -> None:
    grid = small_state_dict[VT + "sphere_grid_2d"] + 4e-6
    frustum = small_state_dict[VT + "frustum"] * (1 + 5e-7)
    small_state_dict.update({VT + "sphere_grid_2d": grid, VT + "frustum": frustum})
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        model, report = load_model("fisheye-bevdet", small_state_dict, config=small_config)
    assert report.source == "checkpoint"
    assert all(torch.equal(torch.from_numpy(g), grid) for g in model.view_transform.geometry.grid)
    assert np.array_equal(model.view_transform.geometry.frustum, frustum.numpy())


def test_bev_grid_mismatch_is_never_overridable(small_config, small_state_dict) -> None:
    small_state_dict[VT + "dx"] = torch.tensor([0.5, 0.6, 10.0])
    with pytest.raises(CheckpointError, match="BEV grid"):
        load_model("fisheye-bevdet", small_state_dict, config=small_config, geometry="checkpoint")


# -- checkpoint files ---------------------------------------------------------------------------


def test_load_checkpoint_files(tmp_path: Path, small_checkpoint: dict) -> None:
    path = tmp_path / "ckpt.pth"
    torch.save(small_checkpoint, path)
    sd, meta = load_checkpoint(path)
    assert meta["arch"] == "fisheye-bevdet" and meta["synthetic"] is True
    assert list(sd) == list(small_checkpoint["state_dict"])
    bare = tmp_path / "bare.pth"
    torch.save({"module." + k: v for k, v in small_checkpoint["state_dict"].items()}, bare)
    sd2, meta2 = load_checkpoint(bare)
    assert list(sd2) == list(sd) and meta2 == {}
    with pytest.raises(CheckpointError, match="no such file"):
        load_checkpoint(tmp_path / "absent.pth")
    torch.save(torch.zeros(3), tmp_path / "tensor.pth")
    with pytest.raises(CheckpointError, match="expected an mmengine checkpoint"):
        load_checkpoint(tmp_path / "tensor.pth")


def test_pickled_objects_need_allow_pickle(tmp_path: Path, small_checkpoint: dict) -> None:
    path = tmp_path / "mmengine.pth"
    torch.save({"state_dict": small_checkpoint["state_dict"], "meta": {"hub": argparse.Namespace(a=1)}}, path)
    with pytest.raises(CheckpointError, match="allow_pickle=True"):
        load_checkpoint(path)
    with pytest.warns(UserWarning, match="execute code"):
        sd, meta = load_checkpoint(path, allow_pickle=True)
    assert meta["hub"].a == 1 and len(sd) == len(small_checkpoint["state_dict"])


# -- synthetic checkpoints ----------------------------------------------------------------------


def test_synthetic_checkpoint_is_seeded_and_calibrated(small_config, small_checkpoint) -> None:
    again = make_checkpoint("fisheye-bevdet", seed=1, config=small_config)["state_dict"]
    sd = small_checkpoint["state_dict"]
    assert all(torch.equal(sd[k], again[k]) for k in sd)
    model = create_model("fisheye-bevdet", small_config)
    init_weights(model, 2)
    assert not torch.equal(sd["img_backbone.conv1.weight"], model.img_backbone.conv1.weight)
    for key in ("img_backbone.layer4.1.bn2", "pts_backbone.blocks.1.4", "bbox_head.heatmap_head.0.bn"):
        var = sd[key + ".running_var"]
        assert torch.all(var > 0) and not torch.allclose(var, torch.ones_like(var))
        assert sd[key + ".num_batches_tracked"].dtype == torch.int64


# -- forward ------------------------------------------------------------------------------------


def _peaks(head: TransFusionHead, dense: torch.Tensor) -> torch.Tensor:
    return head.local_max_nms(torch.sigmoid(dense)).flatten(1)


def test_full_size_forward(full_model) -> None:
    model, _ = full_model
    tables = model.view_transform.tables()
    assert tuple(tables["geom.warp.index"].shape) == (4 * 25 * 100 * 4,)  # four taps per cell of each camera
    assert tuple(tables["geom.warp.weight"].shape) == (4 * 25 * 100, 1, 4)
    images = synthetic_images(42, 1, 4, 800, 800)
    with torch.no_grad():
        out = model(images, return_extras=True)
    boxes, scores, labels, valid = out["boxes"], out["scores"], out["labels"], out["valid"]
    assert boxes.shape == (1, 200, 7) and boxes.dtype == torch.float32
    assert scores.shape == (1, 200) and labels.shape == (1, 200) and valid.shape == (1, 200)
    assert labels.dtype == torch.int64 and valid.dtype == torch.bool
    assert torch.isfinite(boxes).all() and torch.isfinite(scores).all()
    assert out["bev"].shape == (1, 96, 320, 320)
    # centres decode onto the 0.6 m head grid around the lidar: |x|, |y| < 48 + one cell of offsets
    assert boxes[..., :2].abs().max() < 60 and valid.float().mean() > 0.5
    assert (boxes[..., 3:6] > 0).all() and (boxes[..., 6].abs() <= math.pi).all()
    assert ((labels >= 0) & (labels < 6)).all() and (scores >= 0).all() and (scores <= 1).all()
    # heatmap not saturated: top-200 boundary without exact ties; TopK == argsort order
    heat = _peaks(model.bbox_head, out["dense_heatmap"])[0]
    values, order = torch.sort(heat, descending=True, stable=True)
    assert values[199] > values[200]
    assert torch.equal(out["top_indices"][0], order[:200])
    assert len(torch.unique(values[:200])) == 200


def test_small_forward_and_quirks_of_inputs(small_model) -> None:
    images = synthetic_images(3, 2, 4, 160, 160)
    with torch.no_grad():
        out = small_model(images)
    assert set(out) == {"boxes", "scores", "labels", "valid", "rank_scores", "rank_indices"}
    assert out["boxes"].shape == (2, 50, 7) and torch.isfinite(out["boxes"]).all()
    with pytest.raises(FrameError, match="expected \\(B, 4, 160, 160, 3\\)"):
        small_model(images[:, :3])
    cam2lidar = np.stack([small_model.view_transform.geometry.cam2lidar] * 2)
    with torch.no_grad():
        dynamic = small_model.forward_dynamic(images, cam2lidar)
    assert torch.equal(dynamic["labels"], out["labels"])
    assert torch.allclose(dynamic["boxes"], out["boxes"], atol=1e-4)


def test_only_fpn_level_0_is_used(small_model) -> None:
    images = synthetic_images(4, 1, 4, 160, 160)
    with torch.no_grad():
        before = small_model.scene_features(small_model.image_features(images))
        weight = small_model.img_neck.fpn_convs[1].conv.weight
        saved = weight.clone()
        weight.mul_(-3.0)
        after = small_model.scene_features(small_model.image_features(images))
        weight.copy_(saved)
    assert torch.equal(before, after)


def test_extract_bev_is_a_deprecated_alias(small_model) -> None:
    images = synthetic_images(4, 1, 4, 160, 160)
    with torch.no_grad():
        with pytest.warns(DeprecationWarning, match="extract_bev is deprecated"):
            old = small_model.extract_bev(images)
        assert torch.equal(old, small_model.scene_features(small_model.image_features(images)))


def test_bgr_with_rgb_ordered_statistics(small_model) -> None:
    img = torch.zeros(1, 4, 160, 160, 3, dtype=torch.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 10, 20, 30  # B, G, R as cv2 decodes
    x = small_model.normalise(img)
    assert x.shape == (4, 3, 160, 160)
    expected = [(10 - 123.675) / 58.395, (20 - 116.28) / 57.12, (30 - 103.53) / 57.375]
    for c in range(3):
        assert torch.allclose(x[:, c], torch.tensor(expected[c]), atol=1e-6)


def test_grid_uses_width_divisor_and_align_corners(small_model, small_config) -> None:
    vt = small_config.view_transform
    camera = default_rig().shared_model()
    uv = camera.world2cam(spherical_directions(vt.feature_size, vt.azimuth_range, vt.elevation_range).reshape(-1, 3))
    expected = (uv * 2.0 / np.array([camera.width, camera.height]) - 1.0).reshape(*vt.feature_size, 2)
    grid = small_model.view_transform.geometry.grid[0]
    assert np.allclose(grid, expected, atol=1e-6)
    assert not np.allclose(
        grid, (uv * 2.0 / (np.array([camera.width, camera.height]) - 1) - 1.0).reshape(grid.shape), atol=1e-4
    )
    # align_corners=True: a column ramp f(x) = x is sampled at (gx + 1) / 2 * (Wf - 1)
    wf = 10
    ramp = torch.arange(wf, dtype=torch.float32).expand(1, 4, 1, wf, wf).contiguous()
    out = small_model.view_transform.warp(ramp)[0, 0, 0].numpy()
    inside = (np.abs(grid) < 1).all(-1)
    assert np.allclose(out[inside], ((grid[..., 0] + 1) / 2 * (wf - 1))[inside], atol=1e-5)


# -- view transform and pooling -----------------------------------------------------------------


def test_trunc_voxelisation_through_the_plan() -> None:
    cfg = ViewTransformConfig(
        in_channels=8,
        out_channels=2,
        feature_size=(1, 6),
        xbound=(-1.5, 1.5, 1.0),
        ybound=(-1.5, 1.5, 1.0),
        zbound=(-5.0, 5.0, 10.0),
        dbound=(0.5, 1.0, 0.5),
    )
    points = np.array(
        [
            [-1.9, 0.2, 0.0],  # x in (-1, 0) cells below: trunc keeps it in row 0
            [-1.2, 0.2, -12.0],  # z = -12 < -5 but v_z = -0.7: kept
            [0.1, 0.2, -15.5],  # v_z = -1.05: dropped
            [1.5, 0.2, 0.0],  # v_x = 3 = n: dropped
            [1.4, -1.6, 4.9],  # v_y = -0.1: kept in column 0
            [-2.6, 0.0, 0.0],
        ],  # v_x = -1.1: dropped
        dtype=np.float32,
    ).reshape(1, 1, 1, 6, 3)
    bev_grid = BevGrid(cfg.xbound, cfg.ybound, cfg.zbound)
    plan = build_pooling_plan(points, bev_grid)
    params = LSSParams(
        feature_size=cfg.feature_size,
        azimuth_range=cfg.azimuth_range,
        elevation_range=cfg.elevation_range,
        source_size=(2, 2),
        dbound=cfg.dbound,
        xbound=cfg.xbound,
        ybound=cfg.ybound,
        zbound=cfg.zbound,
    )
    geometry = LSSGeometry(
        params=params,
        grid=np.zeros((1, 1, 6, 2), np.float32),
        frustum=points[0],
        cam2lidar=np.eye(4)[None],
        plan=plan,
        valid_fov_mask=np.ones((1, 1, 1, 6), np.float32),
    )
    lss = FisheyeLSS(cfg, geometry)
    depth = torch.arange(1.0, 7.0).reshape(1, 1, 1, 1, 6)
    ctx = torch.tensor([[1.0, -1.0], [3.0, 5.0], [7.0, 7.0], [9.0, 9.0], [2.0, 4.0], [8.0, 8.0]]).reshape(1, 1, 1, 6, 2)
    bev = lss.pool(depth, ctx)[0]  # C x X x Y
    expected = torch.zeros(2, 3, 3)
    expected[:, 0, 1] = (1 * torch.tensor([1.0, -1.0]) + 2 * torch.tensor([3.0, 5.0])) / 2  # mean, not sum
    expected[:, 2, 0] = 5 * torch.tensor([2.0, 4.0])
    assert torch.allclose(bev, expected, atol=1e-6)
    assert plan.counts.tolist() == [0, 2, 0, 0, 0, 0, 1, 0, 0]
    ref = pool_bev_reference(depth[0].numpy(), ctx[0].numpy(), points, bev_grid)
    assert np.allclose(bev.numpy(), ref, atol=1e-6)


def test_torch_pool_equals_numpy_reference(small_model) -> None:
    vt = small_model.view_transform
    g = vt.geometry
    n, d, h, w = g.plan.lift_shape
    gen = torch.Generator().manual_seed(0)
    depth = torch.softmax(torch.randn(1, n, d, h, w, generator=gen), dim=2)
    ctx = torch.randn(1, n, h, w, 32, generator=gen)
    bev = vt.pool(depth, ctx)[0].numpy()
    ref = pool_bev_reference(depth[0].numpy(), ctx[0].numpy(), frustum_to_lidar(g.frustum, g.cam2lidar), g.bev_grid)
    assert bev.shape == ref.shape == (32, 80, 80)
    assert np.abs(bev - ref).max() < 1e-6 * max(1.0, np.abs(ref).max())
    assert (np.abs(ref).sum(0) > 0).sum() > 1000  # a well-populated grid


def test_dynamic_path_matches_baked_plan(small_model) -> None:
    vt = small_model.view_transform
    gen = torch.Generator().manual_seed(1)
    feat = torch.randn(2, 4, 256, 10, 10, generator=gen)
    cam2lidar = torch.from_numpy(np.stack([vt.geometry.cam2lidar] * 2))
    with torch.no_grad():
        assert torch.allclose(vt(feat), vt.forward_dynamic(feat, cam2lidar), atol=1e-6)
        moved = cam2lidar.clone()
        moved[1, :, 0, 3] += 3.0
        dyn = vt.forward_dynamic(feat, moved)
    assert torch.allclose(dyn[0], vt(feat)[0], atol=1e-6) and not torch.allclose(dyn[1], vt(feat)[1], atol=1e-3)


def test_camera_valid_zeroes_context_with_full_rig_counts(small_model) -> None:
    vt = small_model.view_transform
    gen = torch.Generator().manual_seed(2)
    feat = torch.randn(1, 4, 256, 10, 10, generator=gen)
    valid = torch.tensor([[False, True, True, True]])
    with torch.no_grad():
        depth, ctx = vt.lift(feat, None)
        ctx_masked = torch.cat([torch.zeros_like(ctx[:, :1]), ctx[:, 1:]], dim=1)
        expected = vt.pool(depth, ctx_masked)
        assert torch.allclose(vt(feat, valid), expected, atol=1e-7)
        assert torch.equal(vt(feat, torch.ones(1, 4)), vt(feat))


# -- TransFusion head quirks --------------------------------------------------------------------


def _tiny_head(**kwargs) -> TransFusionHead:
    args = dict(
        in_channels=8, hidden_channel=8, num_heads=2, ffn_channels=8, head_conv=4, num_proposals=5, bev_size=(6, 6)
    )
    args.update(kwargs)
    return TransFusionHead(**args).eval()


def test_heatmap_nms_border_and_unsuppressed_classes() -> None:
    head = _tiny_head()
    gen = torch.Generator().manual_seed(3)
    heat = torch.rand(1, 6, 6, 6, generator=gen) * 0.5
    heat[0, :, 0, 2] = 0.9  # border peak
    heat[0, :, 3, 3] = 0.95  # interior peak
    out = head.local_max_nms(heat)[0]
    for c in range(6):
        for i in range(6):
            for j in range(6):
                h = heat[0, c, i, j]
                if c in (4, 5):
                    keep = True
                elif 1 <= i <= 4 and 1 <= j <= 4:
                    keep = bool(h == heat[0, c, i - 1 : i + 2, j - 1 : j + 2].max())
                else:
                    keep = False  # the zero-padded border is never a local max
                assert out[c, i, j] == (h if keep else 0.0), (c, i, j)
    assert out[0, 0, 2] == 0 and out[4, 0, 2] == heat[0, 4, 0, 2] and out[0, 3, 3] == heat[0, 0, 3, 3]


def test_decode_conventions() -> None:
    head = TransFusionHead(num_proposals=4).eval()  # official coder: factor 8, voxel 0.075, pc_range -48
    yaws = torch.tensor([0.3, 2.5, -2.0, math.pi / 2])
    res = {
        "center": torch.tensor([[[10.5, 200.0, 1.5, 80.5], [20.5, 0.5, 2.5, 80.5]]]),
        "height": torch.tensor([[[1.0, 0.0, -4.25, -4.8]]]),
        "dim": torch.log(torch.tensor([[[4.0, 1.0, 1.0, 1.0], [2.0, 1.0, 1.0, 1.0], [1.5, 1.0, 1.5, 1.0]]])),
        "rot": torch.stack([torch.sin(yaws), torch.cos(yaws)])[None],
        "heatmap": torch.zeros(1, 6, 4),
    }
    cls = torch.tensor([[2, 4, 3, 1]])
    peak = torch.full((1, 6, 4), 0.8)
    peak[0, 3, 2] = 0.0  # the proposal's own class peak is zero -> score 0, label 0
    out = head.decode(res, peak, cls)
    boxes = out["boxes"][0]
    assert torch.allclose(boxes[0, :2], torch.tensor([10.5 * 8 * 0.075 - 48, 20.5 * 8 * 0.075 - 48]))
    assert torch.allclose(boxes[0, 3:6], torch.tensor([4.0, 2.0, 1.5]))  # exp of log sizes, (l, w, h)
    assert torch.isclose(boxes[0, 2], torch.tensor(0.25))  # z bottom = centre z - h / 2
    assert torch.allclose(boxes[:, 6], yaws, atol=1e-6)  # yaw = atan2(sin, cos); pi/2 faces +y (left)
    assert torch.allclose(out["rot"][0], torch.stack([torch.sin(yaws), torch.cos(yaws)], -1))
    assert torch.allclose(out["scores"][0], torch.tensor([0.4, 0.4, 0.0, 0.4]))  # sigmoid(0) * peak
    assert out["labels"][0].tolist() == [2, 4, 0, 1]
    # post_center_range is inclusive on (x, y, z_bottom): z_bottom = -5 kept, x = 72 and z = -5.3 not
    assert out["valid"][0].tolist() == [True, False, True, False]


def test_decoder_value_includes_position_embedding() -> None:
    torch.manual_seed(0)
    layer = TransFusionDecoderLayer(16, 2, 32).eval()
    query, key = torch.randn(1, 5, 16), torch.randn(1, 7, 16)
    qpos, kpos = torch.rand(1, 5, 2) * 10, torch.rand(1, 7, 2) * 10
    mha = [torch.nn.MultiheadAttention(16, 2) for _ in range(2)]
    for ref, ours in zip(mha, (layer.self_attn.attn, layer.cross_attn.attn)):
        ref.load_state_dict(ours.state_dict())
        ref.eval()
    with torch.no_grad():
        qe, ke = layer.self_posembed(qpos), layer.cross_posembed(kpos)
        t = lambda x: x.transpose(0, 1)  # noqa: E731  (torch MHA is sequence-first)
        x = query + qe
        q1 = layer.norms[0](query + t(mha[0](t(x), t(x), t(x))[0]))
        kv = key + ke
        q2 = layer.norms[1](q1 + t(mha[1](t(q1 + qe), t(kv), t(kv))[0]))
        expected = layer.norms[2](q2 + layer.ffn(q2))
        detr_style = layer.norms[0](query + t(mha[0](t(x), t(x), t(query))[0]))
        assert torch.allclose(layer(query, key, qpos, kpos), expected, atol=1e-5)
        assert not torch.allclose(detr_style, q1, atol=1e-3)


def test_topk_semantics_and_class_encoding(small_model) -> None:
    with torch.no_grad():
        out = small_model(synthetic_images(8, 1, 4, 160, 160), return_extras=True)
    head = small_model.bbox_head
    heat = _peaks(head, out["dense_heatmap"])[0]
    values, order = torch.sort(heat, descending=True, stable=True)
    assert torch.equal(out["top_indices"][0], order[:50]) and values[49] > values[50]
    cells = 40 * 40
    assert torch.equal(out["query_labels"][0], order[:50] // cells)


# -- configuration ------------------------------------------------------------------------------


def test_from_mmdet3d_config_matches_official_defaults() -> None:
    cfg = BEVDetConfig.from_mmdet3d_config(DATA / "fisheye_bevdet.py")
    assert cfg == BEVDetConfig()
    raw = read_mmdet3d_config(DATA / "fisheye_bevdet.py")
    assert raw["param_scheduler"][2]["T_max"] == 8 and raw["test_dataloader"] is raw["val_dataloader"]
    assert cfg.view_transform.azimuth_range == (-math.radians(110), math.radians(110))
    assert cfg.image.mean == (123.675, 116.28, 103.53) and cfg.head.unsuppressed_classes == (4, 5)
    assert BEVDetConfig.from_dict(cfg.to_dict()) == cfg


def test_config_variant_is_mapped(tmp_path: Path) -> None:
    text = (DATA / "fisheye_bevdet.py").read_text()
    text = text.replace("num_proposals=200", "num_proposals=100").replace(
        "dbound=[0.5, 48.5, 0.5]", "dbound=[1.0, 49.0, 1.0]"
    )
    path = tmp_path / "variant.py"
    path.write_text(text)
    cfg = BEVDetConfig.from_mmdet3d_config(path)
    assert cfg.head.num_proposals == 100 and cfg.view_transform.num_depth_bins == 48


@pytest.mark.parametrize(
    "line, construct",
    [
        ("import os", "import of module 'os'"),
        ("x = open('/etc/passwd')", "function call"),
        ("y = __import__('os').system('true')", "function call"),
        ("z = math.sys", "attribute access"),
        ("u = math.floor(2.5)", "function call"),
        ("w = [i for i in range(3)]", "ListComp"),
        ("v = undefined_name + 1", "name 'undefined_name'"),
        ("def f():\n    pass", "FunctionDef"),
        ("f = lambda: 0", "Lambda"),
        ("g = ((10 ** 64) ** 64) ** 64", "an integer of more than 4096 bits"),
    ],
)
def test_config_refuses_code(tmp_path: Path, line: str, construct: str) -> None:
    text = (DATA / "fisheye_bevdet.py").read_text()
    path = tmp_path / "evil.py"
    path.write_text(text + "\n" + line + "\n")
    lineno = len(text.splitlines()) + 2
    with pytest.raises(ConfigError) as err:
        read_mmdet3d_config(path)
    assert f"line {lineno}" in str(err.value) and construct in str(err.value)


def test_inconsistent_config_is_refused() -> None:
    with pytest.raises(ConfigError, match="view_transform.out_channels=64"):
        BEVDetConfig().replace(view_transform={"out_channels": 64})
    with pytest.raises(ConfigError, match="grid_size"):
        BEVDetConfig().replace(head={"grid_size": (1024, 1024, 40)})


def test_official_tables_are_accepted_and_used_exactly(full_checkpoint: dict, official: dict) -> None:
    """The tables the official constructor computes for the shipped rig pass the geometry check
    (including sphere_grid_3d, whose horizon rays flip to the sentinel in some depth slices)."""
    sd = dict(full_checkpoint["state_dict"])
    for key in ("frustum", "sphere_grid_3d", "sphere_grid_2d", "valid_fov_mask", "dx", "bx", "nx"):
        sd[VT + key] = torch.from_numpy(official["fisheye_bevdet/" + VT + key])
    model, report = load_model("fisheye-bevdet", {"state_dict": sd, "meta": {}})
    assert report.source == "checkpoint"
    assert all(torch.equal(torch.from_numpy(g), sd[VT + "sphere_grid_2d"]) for g in model.view_transform.geometry.grid)
    np.testing.assert_array_equal(model.view_transform.geometry.frustum, official["fisheye_bevdet/" + VT + "frustum"])
    assert model.view_transform.geometry.plan.num_kept == pytest.approx(554_668, abs=50)
