"""FisheyePETR: checkpoint compatibility, forward behaviour and the official quirks, pinned by hand.

Most tests use a reduced configuration (64 px images, a 5 x 21 angular grid, 40 queries); one
test runs the full-size model on a synthetic checkpoint of the official layout.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import torch
import torch.nn.functional as F

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.errors import CheckpointError, ConfigError, FrameError
from fisheye_infer.geometry.petr import PETRGeometry, lid_depths, position_coords, sine_position_encoding
from fisheye_infer.models import load_model
from fisheye_infer.models.checkpoint import GeometryReport
from fisheye_infer.models.fisheye_petr import GEOMETRY_KEYS, FisheyePETR, checkpoint_filter_fn, rename_official_keys
from fisheye_infer.models.official_loading import load_official_state_dict
from fisheye_infer.models.petr_config import PETRConfig
from fisheye_infer.models.petr_embedding import inverse_sigmoid, pos2posemb3d
from fisheye_infer.models.petr_head import decode_predictions
from fisheye_infer.models.petr_transformer import (
    QUERY_CHUNK,
    MultiheadAttention,
    PETRTransformerDecoder,
    key_padding_bias,
)
from fisheye_infer.models.ranking import TopK
from fisheye_infer.models.registry import create_model, list_models, read_manifest
from fisheye_infer.models.seeded_checkpoint import make_checkpoint, synthetic_images

SMALL = PETRConfig().replace(
    image={"height": 64, "width": 64}, head={"feature_size": (5, 21), "num_query": 40, "max_num": 30}
)
LOGIT_MAX = math.log(1 / 1e-5)  # 11.5129


@pytest.fixture(scope="module")
def small_ckpt() -> dict[str, torch.Tensor]:
    return make_checkpoint("fisheye-petr", 1, config=SMALL)["state_dict"]


@pytest.fixture(scope="module")
def full_ckpt() -> dict[str, torch.Tensor]:
    return make_checkpoint("fisheye-petr", 0)["state_dict"]


@pytest.fixture(scope="module")
def full_petr(full_ckpt: dict[str, torch.Tensor]) -> tuple[FisheyePETR, GeometryReport]:
    return load_model("fisheye-petr", {"state_dict": full_ckpt})


def _small_model(state_dict: dict[str, torch.Tensor], geometry: PETRGeometry | None = None) -> FisheyePETR:
    model = FisheyePETR(SMALL, geometry=geometry)
    load_official_state_dict(model, state_dict, geometry="rig" if geometry is not None else "verify")
    return model


@pytest.fixture(scope="module")
def small_petr(small_ckpt: dict[str, torch.Tensor]) -> FisheyePETR:
    return _small_model(small_ckpt)


def _run(model: FisheyePETR, images: torch.Tensor, **kw: object) -> dict[str, torch.Tensor]:
    with torch.no_grad():
        return model(images, **kw)


# -- checkpoint layout --------------------------------------------------------------------------


def test_registered() -> None:
    assert "fisheye-petr" in list_models()
    model = create_model("fisheye-petr", SMALL)
    assert isinstance(model, FisheyePETR) and not model.training


def test_official_keys_match_manifest() -> None:
    model = FisheyePETR()
    manifest = read_manifest("fisheye-petr")
    keys = model.official_keys()
    assert list(keys) == [e["key"] for e in manifest]  # 354 keys, official order
    assert len(keys) == 354
    for e in manifest:
        assert keys[e["key"]][0] == tuple(e["shape"]), e["key"]
    official = model.official_state_dict()
    assert list(official) == list(keys)
    assert set(model.state_dict()) == set(keys) - set(GEOMETRY_KEYS)


def test_strict_load_of_synthetic_checkpoint(
    full_ckpt: dict[str, torch.Tensor], full_petr: tuple[FisheyePETR, GeometryReport]
) -> None:
    model, report = full_petr
    assert report.source == "checkpoint"
    weights = model.state_dict()
    for key, value in checkpoint_filter_fn(full_ckpt).items():
        assert torch.equal(weights[key], value), key
    stored = full_ckpt["pts_bbox_head.sphere_grid_2d"]
    assert all(torch.equal(torch.from_numpy(g), stored) for g in model.pts_bbox_head.geometry.grid)


@pytest.mark.parametrize(
    "edit, named",
    [
        ("drop", "pts_bbox_head.transformer.decoder.layers.3.norms.1.bias"),  # missing weight
        ("drop", "pts_bbox_head.unvalid_area"),  # missing geometry table
        ("drop", "img_neck.fpn_convs.1.conv.weight"),  # dead at inference, still required
        ("add", "pts_bbox_head.extra_branch.weight"),  # unexpected key
    ],
)
def test_bad_key_is_named(small_ckpt: dict[str, torch.Tensor], edit: str, named: str) -> None:
    sd = dict(small_ckpt)
    if edit == "drop":
        del sd[named]
    else:
        sd[named] = torch.zeros(3)
    with pytest.raises(CheckpointError, match=named.replace(".", r"\.")):
        load_official_state_dict(FisheyePETR(SMALL), sd)


def test_shared_branches_are_one_module(small_ckpt: dict[str, torch.Tensor], small_petr: FisheyePETR) -> None:
    head = small_petr.pts_bbox_head
    assert all(b is head.cls_branches[0] for b in head.cls_branches)
    assert all(b is head.reg_branches[0] for b in head.reg_branches)
    for k in range(6):  # every copy in the checkpoint equals the loaded weights
        assert torch.equal(small_ckpt[f"pts_bbox_head.reg_branches.{k}.4.weight"], head.reg_branches[0][4].weight)


def test_differing_branch_copy_is_refused(small_ckpt: dict[str, torch.Tensor]) -> None:
    sd = dict(small_ckpt)
    key = "pts_bbox_head.reg_branches.3.2.weight"
    sd[key] = sd[key] + 1.0
    with pytest.raises(CheckpointError, match=r"reg_branches\.3\.2\.weight"):
        load_official_state_dict(FisheyePETR(SMALL), sd)


def test_rename_official_keys() -> None:
    t = torch.zeros(1)
    old = {
        "state_dict": {
            "module.pts_bbox_head.transformer.decoder.layers.0.self_attn.attn.in_proj_weight": t,
            "module.pts_bbox_head.transformer.decoder.layers.0.multihead_attn.attn.in_proj_bias": t,
            "module.pts_bbox_head.transformer.decoder.norm.weight": t,
            "module.img_neck.fpn_convs.0.conv.bias": t,
        }
    }
    assert list(rename_official_keys(old)) == [
        "pts_bbox_head.transformer.decoder.layers.0.attentions.0.attn.in_proj_weight",
        "pts_bbox_head.transformer.decoder.layers.0.attentions.1.attn.in_proj_bias",
        "pts_bbox_head.transformer.decoder.post_norm.weight",
        "img_neck.fpn_convs.0.conv.bias",
    ]


def test_geometry_policy(small_ckpt: dict[str, torch.Tensor]) -> None:
    sd = dict(small_ckpt)
    shifted = sd["pts_bbox_head.sphere_grid_2d"] + 1e-3
    sd["pts_bbox_head.sphere_grid_2d"] = shifted
    sd["pts_bbox_head.sphere_grid_3d"] = torch.cat(
        [
            shifted.expand(sd["pts_bbox_head.sphere_grid_3d"].shape[0], -1, -1, -1),
            sd["pts_bbox_head.sphere_grid_3d"][..., 2:],
        ],
        dim=-1,
    )
    with pytest.raises(CheckpointError, match="sphere_grid_2d"):
        load_official_state_dict(FisheyePETR(SMALL), sd)
    model = FisheyePETR(SMALL)
    with pytest.warns(UserWarning, match="stored"):
        assert load_official_state_dict(model, sd, geometry="checkpoint").source == "checkpoint"
    assert all(torch.equal(torch.from_numpy(g), shifted) for g in model.pts_bbox_head.geometry.grid)
    with pytest.warns(UserWarning, match="recomputed"):
        load_official_state_dict(model, sd, geometry="rig")
    assert np.array_equal(model.pts_bbox_head.geometry.grid, model.rig_geometry.grid)


def test_stored_mask_rounding_cells_are_kept(small_ckpt: dict[str, torch.Tensor]) -> None:
    # A float32 rounding residue (1 - v = 5.96e-8) agrees with the recomputation within tolerance,
    # so the stored table wins and the cell is masked, as in the official model.
    sd = dict(small_ckpt)
    mask = sd["pts_bbox_head.unvalid_area"].clone()
    assert mask[0, 0, 2, 10] == 0
    mask[0, 0, 2, 10] = 5.96e-8
    sd["pts_bbox_head.unvalid_area"] = mask
    model = FisheyePETR(SMALL)
    assert load_official_state_dict(model, sd).source == "checkpoint"
    assert bool(model.pts_bbox_head.key_mask()[0, :, 2, 10].all())


def test_official_tables_are_accepted(full_ckpt: dict[str, torch.Tensor], official: dict[str, np.ndarray]) -> None:
    # Tables the official constructor computes for the shipped rig: float32 world2cam flips a few
    # horizon cells of sphere_grid_3d to the sentinel at some depths, and the mask's rounding
    # cells differ from a float64 recomputation. Verification passes and the stored mask is used.
    sd = dict(full_ckpt)
    for key in GEOMETRY_KEYS:
        sd[key] = torch.from_numpy(official["fisheye_petr/" + key])
    model = FisheyePETR()
    assert load_official_state_dict(model, sd).source == "checkpoint"
    stored = official["fisheye_petr/pts_bbox_head.unvalid_area"][0, 0] != 0
    assert np.array_equal(model.pts_bbox_head.key_mask()[0, 0].numpy(), stored)
    assert not np.array_equal(model.rig_geometry.unvalid_area != 0, stored)


# -- forward ------------------------------------------------------------------------------------


def test_full_size_forward(full_petr: tuple[FisheyePETR, GeometryReport]) -> None:
    model = full_petr[0]
    out = _run(model, synthetic_images(11, 1, 4, 800, 800), camera_valid=torch.ones(1, 4, dtype=torch.bool))
    boxes, scores, labels, valid = out["boxes"], out["scores"], out["labels"], out["valid"]
    assert boxes.shape == (1, 300, 7) and scores.shape == labels.shape == valid.shape == (1, 300)
    assert labels.dtype == torch.int64 and valid.dtype == torch.bool
    assert torch.isfinite(boxes).all() and bool(valid.all())
    assert bool((scores[0, :-1] >= scores[0, 1:]).all()) and float(scores.min()) > 0 and float(scores.max()) < 1
    assert int(labels.min()) >= 0 and int(labels.max()) < 6
    b = boxes[0]
    assert float(b[:, :2].abs().max()) <= 48.0  # centres inside point_cloud_range (lidar frame)
    z_centre = b[:, 2] + b[:, 5] / 2
    assert float(z_centre.min()) >= -5.0 and float(z_centre.max()) <= 5.0
    assert bool((b[:, 3:6] > 0).all()) and float(b[:, 6].min()) >= -math.pi and float(b[:, 6].max()) < math.pi
    # the queries do not collapse: distinct boxes spread over the range
    assert torch.unique(b, dim=0).shape[0] >= 250
    assert float(b[:, 0].std()) > 5.0 and float(b[:, 1].std()) > 5.0


def test_batch_samples_are_independent(small_petr: FisheyePETR) -> None:
    images = synthetic_images(4, 2, 4, 64, 64)
    both = _run(small_petr, images)
    one = _run(small_petr, images[1:])
    assert both["boxes"].shape == (2, 30, 7) and torch.isfinite(both["boxes"]).all()
    torch.testing.assert_close(both["boxes"][1:], one["boxes"], rtol=1e-5, atol=1e-4)
    assert torch.equal(both["labels"][1:], one["labels"])


def test_missing_camera_is_ignored(small_petr: FisheyePETR) -> None:
    images = synthetic_images(5, 1, 4, 64, 64)
    other = images.clone()
    other[:, 2] = 255 - other[:, 2]
    valid = torch.tensor([[True, True, False, True]])
    a, b = _run(small_petr, images, camera_valid=valid), _run(small_petr, other, camera_valid=valid)
    assert torch.equal(a["boxes"], b["boxes"]) and torch.equal(a["scores"], b["scores"])
    full = _run(small_petr, images, camera_valid=torch.ones(1, 4, dtype=torch.bool))
    assert torch.equal(full["boxes"], _run(small_petr, images)["boxes"])
    assert not torch.equal(full["scores"], a["scores"])


def test_dynamic_cam2lidar_matches_baked(small_petr: FisheyePETR) -> None:
    images = synthetic_images(6, 1, 4, 64, 64)
    baked = _run(small_petr, images)
    c2l = small_petr.rig_geometry.cam2lidar[None]
    dynamic = _run(small_petr, images, cam2lidar=c2l)
    torch.testing.assert_close(dynamic["boxes"], baked["boxes"], rtol=0, atol=1e-5)
    moved = c2l.copy()
    moved[..., 0, 3] += 5.0
    assert not torch.allclose(_run(small_petr, images, cam2lidar=moved)["scores"], baked["scores"])


def test_cached_embeddings_follow_loads(small_ckpt: dict[str, torch.Tensor]) -> None:
    model = FisheyePETR(SMALL)
    before = model.pts_bbox_head.key_pos.clone()
    load_official_state_dict(model, small_ckpt)
    head = model.pts_bbox_head
    with torch.no_grad():
        pe = head.position_embedding().permute(0, 1, 3, 4, 2).reshape(head.key_pos.shape)
        assert torch.equal(head.key_pos, pe) and not torch.equal(head.key_pos, before)
        assert torch.equal(head.query_pos, head.query_positions())


def test_warp_equals_per_camera_grid_sample(small_petr: FisheyePETR) -> None:
    head = small_petr.pts_bbox_head
    p3 = torch.randn(2, 4, 256, 4, 4, generator=torch.Generator().manual_seed(0))
    grid = torch.from_numpy(head.geometry.grid).repeat(2, 1, 1, 1)  # camera by camera, for both samples
    official = F.grid_sample(p3.flatten(0, 1), grid, mode="bilinear", padding_mode="zeros", align_corners=True)
    torch.testing.assert_close(head.warp(p3), official.reshape(2, 4, 256, 5, 21), rtol=0, atol=1e-6)


def test_normalisation_uses_rgb_stats_on_bgr(small_petr: FisheyePETR) -> None:
    img = torch.zeros(1, 4, 96, 96, 3, dtype=torch.uint8)
    img[..., 0], img[..., 1], img[..., 2] = 10, 20, 30  # B, G, R
    x = small_petr.normalise(img)[0, :, 0, 0]
    expected = [(10 - 123.675) / 58.395, (20 - 116.28) / 57.12, (30 - 103.53) / 57.375]
    torch.testing.assert_close(x, torch.tensor(expected), rtol=1e-6, atol=1e-6)


def test_the_stages_compose_to_predict(small_petr: FisheyePETR) -> None:
    """predict runs the head as one module call; the named stages must give the same numbers."""
    img = torch.randint(0, 256, (2, 4, 96, 96, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(1))
    valid = torch.tensor([[True, True, False, True], [True, True, True, True]])
    with torch.no_grad():
        whole = small_petr.predict(img, valid)
        feats = small_petr.image_features(img)
        staged = small_petr.head_outputs(small_petr.scene_features(feats, valid))
    assert feats.shape[:2] == (2, 4)
    for key, value in whole.items():
        torch.testing.assert_close(staged[key], value, rtol=0, atol=0)


def test_old_stage_names_are_deprecated_aliases(small_petr: FisheyePETR) -> None:
    img = torch.randint(0, 256, (1, 4, 96, 96, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    with torch.no_grad():
        with pytest.warns(DeprecationWarning, match="normalize is deprecated"):
            torch.testing.assert_close(small_petr.normalize(img), small_petr.normalise(img), rtol=0, atol=0)
        with pytest.warns(DeprecationWarning, match="forward_features is deprecated"):
            torch.testing.assert_close(small_petr.forward_features(img), small_petr.image_features(img), rtol=0, atol=0)


def test_wrong_image_shape_is_refused(small_petr: FisheyePETR) -> None:
    with pytest.raises(FrameError, match="images"):
        small_petr(torch.zeros(1, 3, 96, 96, 3, dtype=torch.uint8))


# -- transformer --------------------------------------------------------------------------------


def test_attention_matches_torch_multihead_attention() -> None:
    torch.manual_seed(0)
    mine = MultiheadAttention(64, 8).eval()
    ref = torch.nn.MultiheadAttention(64, 8).eval()
    ref.load_state_dict(mine.state_dict())  # same parameter layout and names
    q, k, v = torch.randn(2, 7, 64), torch.randn(2, 11, 64), torch.randn(2, 11, 64)
    mask = torch.rand(2, 11) < 0.3
    mask[:, 0] = False
    out = mine(q, k, v, key_padding_bias(mask))
    expected = ref(q.transpose(0, 1), k.transpose(0, 1), v.transpose(0, 1), key_padding_mask=mask)[0]
    torch.testing.assert_close(out, expected.transpose(0, 1), rtol=1e-5, atol=1e-6)
    # one bias row for the whole batch (the static key mask of the rig)
    shared = mask[:1].expand(2, -1)
    expected = ref(q.transpose(0, 1), k.transpose(0, 1), v.transpose(0, 1), key_padding_mask=shared)[0]
    torch.testing.assert_close(
        mine(q, k, v, key_padding_bias(mask[:1])), expected.transpose(0, 1), rtol=1e-5, atol=1e-6
    )
    # every key ignored (all cameras invalid): uniform attention, finite, where torch gives NaN
    everything = torch.ones(1, 11, dtype=torch.bool)
    v_proj = torch.nn.functional.linear(v, mine.in_proj_weight[128:], mine.in_proj_bias[128:])
    uniform = mine.out_proj(v_proj.mean(dim=1, keepdim=True)).expand(2, 7, 64)
    torch.testing.assert_close(mine(q, k, v, key_padding_bias(everything)), uniform, rtol=1e-5, atol=1e-6)


def test_attention_in_query_chunks_matches_torch_multihead_attention() -> None:
    """More queries than ``QUERY_CHUNK``, the last chunk partial: torch's attention over all of them at once."""
    torch.manual_seed(1)
    mine = MultiheadAttention(32, 4).eval()
    ref = torch.nn.MultiheadAttention(32, 4).eval()
    ref.load_state_dict(mine.state_dict())
    q, k, v = torch.randn(2, 2 * QUERY_CHUNK + 7, 32), torch.randn(2, 50, 32), torch.randn(2, 50, 32)
    mask = torch.rand(2, 50) < 0.3
    expected = ref(q.transpose(0, 1), k.transpose(0, 1), v.transpose(0, 1), key_padding_mask=mask)[0]
    torch.testing.assert_close(mine(q, k, v, key_padding_bias(mask)), expected.transpose(0, 1), rtol=1e-5, atol=1e-6)


@pytest.mark.parametrize("ignored", ["some keys", "every key", "none"])
def test_training_attention_equals_the_exported_graph(ignored: str) -> None:
    """Training mode runs PyTorch's fused attention; its outputs and every gradient are the explicit graph's."""
    torch.manual_seed(0)
    explicit = MultiheadAttention(32, 4).eval()
    fused = MultiheadAttention(32, 4).train()
    fused.load_state_dict(explicit.state_dict())
    q, k, v = torch.randn(2, 9, 32), torch.randn(2, 13, 32), torch.randn(2, 13, 32)
    mask = {"some keys": torch.rand(1, 13) < 0.4, "every key": torch.ones(1, 13, dtype=torch.bool)}.get(ignored)
    bias = None if mask is None else key_padding_bias(mask)
    outputs = []
    for module in (explicit, fused):
        inputs = [x.clone().requires_grad_() for x in (q, k, v)]
        out = module(*inputs, bias)
        assert _autograd_names(out) & {"SoftmaxBackward0"} == ({"SoftmaxBackward0"} if module is explicit else set())
        (out * torch.linspace(-1, 1, out.numel()).reshape(out.shape)).sum().backward()
        grads = [x.grad for x in inputs] + [p.grad for p in module.parameters()]
        outputs.append((out.detach(), grads))
    torch.testing.assert_close(outputs[1][0], outputs[0][0], rtol=1e-5, atol=1e-6)
    if ignored == "every key":
        return  # uniform attention whatever the logits: no gradient to compare (training always has keys)
    for got, want in zip(outputs[1][1], outputs[0][1]):
        torch.testing.assert_close(got, want, rtol=1e-4, atol=1e-6)


def _autograd_names(out: torch.Tensor) -> set[str]:
    """The names of the autograd nodes that computed ``out``: which graph ran."""
    names, stack, seen = set(), [out.grad_fn], set()
    while stack:
        node = stack.pop()
        if node is None or node in seen:
            continue
        seen.add(node)
        names.add(type(node).__name__)
        stack.extend(next_node for next_node, _ in node.next_functions)
    return names


def _reference_layer(
    layer: torch.nn.Module, t: torch.Tensor, mem: torch.Tensor, qp: torch.Tensor, kp: torch.Tensor, mask: torch.Tensor
) -> torch.Tensor:
    """mmcv BaseTransformerLayer, post-norm order, with torch's MultiheadAttention (sequence-first)."""

    def mha(block: torch.nn.Module, q, k, v, kpm=None):  # noqa: ANN001, ANN202
        ref = torch.nn.MultiheadAttention(q.shape[-1], block.attn.num_heads)
        ref.load_state_dict(block.attn.state_dict())
        return ref.eval()(q.transpose(0, 1), k.transpose(0, 1), v.transpose(0, 1), key_padding_mask=kpm)[0].transpose(
            0, 1
        )

    t = t + mha(layer.attentions[0], t + qp, t + qp, t)
    t = layer.norms[0](t)
    t = t + mha(layer.attentions[1], t + qp, mem + kp, mem, mask)
    t = layer.norms[1](t)
    t = t + layer.ffns[0].layers[1](torch.relu(layer.ffns[0].layers[0][0](t)))
    return layer.norms[2](t)


def test_decoder_post_norm_only_on_outputs() -> None:
    torch.manual_seed(1)
    dec = PETRTransformerDecoder(num_layers=3, embed_dims=32, num_heads=4, ffn_dims=64).eval()
    with torch.no_grad():
        for p in dec.parameters():
            p.add_(0.1 * torch.randn_like(p))
    t0, mem = torch.zeros(1, 5, 32), torch.randn(1, 9, 32)
    qp, kp = torch.randn(1, 5, 32), torch.randn(1, 9, 32)
    mask = torch.zeros(1, 9, dtype=torch.bool)
    mask[0, 3] = True
    with torch.no_grad():
        outs = dec(t0, mem, qp, kp, key_padding_bias(mask), return_intermediate=True)
        last = dec(t0, mem, qp, kp, key_padding_bias(mask))
        t = t0
        for i, layer in enumerate(dec.layers):
            t = _reference_layer(layer, t, mem, qp, kp, mask)  # carried tensor is NOT post-normed
            torch.testing.assert_close(outs[i], dec.post_norm(t), rtol=1e-5, atol=1e-5)
        wrong = _reference_layer(
            dec.layers[1], dec.post_norm(_reference_layer(dec.layers[0], t0, mem, qp, kp, mask)), mem, qp, kp, mask
        )
    torch.testing.assert_close(last, outs[-1])
    assert not torch.allclose(outs[1], dec.post_norm(wrong), atol=1e-3)


# -- quirks pinned by hand ----------------------------------------------------------------------


def test_lid_depths() -> None:
    d = lid_depths(64, 0.5, 60.0)
    np.testing.assert_allclose(d[:5], [0.5, 0.52861, 0.58582, 0.67163, 0.78606], atol=1e-5)
    np.testing.assert_allclose(d[-3:], [54.5935, 56.3671, 58.1692], atol=1e-4)


def _identity_geometry() -> PETRGeometry:
    g = PETRGeometry.from_rig(default_rig(), SMALL.geometry_params())
    return dataclasses.replace(g, cam2lidar=np.repeat(np.eye(4)[None], 4, axis=0))


def test_position_coords_with_identity_extrinsics(small_ckpt: dict[str, torch.Tensor]) -> None:
    model = _small_model(small_ckpt, _identity_geometry())
    coords = model.pts_bbox_head.coords3d  # N x 3D x H x W, channel 3*i + axis
    d = lid_depths(64, 0.5, 60.0)
    # centre column (azimuth 0): x = d cos(el) sin(0) = 0 -> logit(0.5) = 0, for every depth
    torch.testing.assert_close(coords[:, 0::3, :, 10], torch.zeros_like(coords[:, 0::3, :, 10]), rtol=0, atol=1e-6)
    # centre cell looks along +z: z = d_i, normalised (d_i + 10) / 20, depth-major channels
    near = d < 10
    c = (d[near] + 10) / 20
    expected = np.log(c / (1 - c))
    np.testing.assert_allclose(coords[0, 2::3, 2, 10].numpy()[near], expected, atol=1e-5)
    # full size: the two centre columns are mirror images (W = 100 has no column at azimuth 0)
    full = position_coords(np.eye(4)[None], (25, 100))
    np.testing.assert_allclose(full[0, 0, :, 49], -full[0, 0, :, 50], atol=1e-6)
    assert abs(float(full[0, 0, 12, 49])) < 1e-3


def test_inverse_sigmoid_saturation() -> None:
    out = inverse_sigmoid(torch.tensor([-0.5, 0.0, 0.5, 1.0, 1.5]))
    torch.testing.assert_close(out, torch.tensor([-LOGIT_MAX, -LOGIT_MAX, 0.0, LOGIT_MAX, LOGIT_MAX]))
    assert abs(LOGIT_MAX - 11.5129) < 1e-4
    far = np.repeat(np.eye(4)[None], 4, axis=0)
    far[:, 0, 3] = 1000.0  # every point beyond position_range in +x
    coords = position_coords(far, (5, 21))
    np.testing.assert_allclose(coords[:, 0::3], LOGIT_MAX, atol=1e-4)


def official_sine_encoding(mask: torch.Tensor, num_feats: int = 128) -> torch.Tensor:
    """SinePositionalEncoding3D(num_feats, normalize=True) of a (B, N, H, W) bool mask, written
    straight from the official formula: float32 cumsums, then per block stack((sin, cos), dim=4)."""
    b, n, h, w = mask.shape
    not_mask = ~mask
    eps, scale = 1e-6, 2 * math.pi
    embeds = [not_mask.cumsum(axis, dtype=torch.float32) for axis in (1, 2, 3)]
    embeds[0] = embeds[0] / (embeds[0][:, -1:, :, :] + eps) * scale
    embeds[1] = embeds[1] / (embeds[1][:, :, -1:, :] + eps) * scale
    embeds[2] = embeds[2] / (embeds[2][:, :, :, -1:] + eps) * scale
    dim_t = torch.arange(num_feats, dtype=torch.float32)
    dim_t = 10000 ** (2 * (dim_t // 2) / num_feats)
    parts = []
    for e in embeds:
        p = e[:, :, :, :, None] / dim_t
        parts.append(torch.stack((p[:, :, :, :, 0::2].sin(), p[:, :, :, :, 1::2].cos()), dim=4).view(b, n, h, w, -1))
    return torch.cat(parts, dim=4).permute(0, 1, 4, 2, 3)


def _interleaved(pe: np.ndarray, num_feats: int = 128) -> np.ndarray:
    """The same values in the interleaved layout (sin, cos, sin, cos, ...) per block."""
    n, c, h, w = pe.shape
    blocks = pe.reshape(n, 3, 2, num_feats // 2, h, w)  # (camera, block, sin|cos, frequency pair)
    return blocks.transpose(0, 1, 3, 2, 4, 5).reshape(n, c, h, w)


def _odd_mask() -> np.ndarray:
    rng = np.random.default_rng(7)
    mask = rng.random((4, 5, 7)) < 0.25
    mask[:, 2, :] = True  # a fully masked row
    mask[1] = rng.random((5, 7)) < 0.6  # cameras differ, so the camera counts do too
    return mask


@pytest.mark.parametrize("source", ["random", "model"])
def test_sine_encoding_equals_the_official_formula_on_every_channel(source: str, small_petr: FisheyePETR) -> None:
    mask = _odd_mask() if source == "random" else small_petr.pts_bbox_head.key_mask()[0].numpy()
    ours = sine_position_encoding(mask)
    official = official_sine_encoding(torch.from_numpy(mask)[None])[0].numpy()
    assert ours.shape == official.shape == (mask.shape[0], 384, *mask.shape[1:])
    np.testing.assert_allclose(ours, official, rtol=0, atol=2e-6)


def test_sine_encoding_is_blocked_not_interleaved() -> None:
    mask = _odd_mask()
    ours = sine_position_encoding(mask)
    official = official_sine_encoding(torch.from_numpy(mask)[None])[0].numpy()
    assert np.array_equal(ours[:, 0], _interleaved(ours)[:, 0])  # channel 0 cannot tell the layouts apart
    assert np.abs(_interleaved(ours) - official).max() > 0.5  # the interleaved layout is not the official one
    full = sine_position_encoding(np.zeros((4, 2, 3), bool))
    a = 1 / (4 + 1e-6) * 2 * math.pi  # camera 0 of four valid cameras
    np.testing.assert_allclose(full[0, 64], math.cos(a), atol=1e-6)  # the cosines start at channel 64


def test_sine_encoding_of_shared_mask(small_petr: FisheyePETR) -> None:
    mask = small_petr.pts_bbox_head.key_mask()[0].numpy()  # 4 x H x W, the same for every camera
    pe = sine_position_encoding(mask)  # 4 x 384 x H x W
    valid = ~mask[0]
    for n in range(4):
        a = (n + 1) / (4 + 1e-6) * 2 * math.pi
        np.testing.assert_allclose(pe[n, 0][valid], math.sin(a), atol=1e-6)
        np.testing.assert_allclose(pe[n, 64][valid], math.cos(a), atol=1e-6)
        np.testing.assert_allclose(pe[n, 1][valid], math.sin(a / 10000 ** (2 / 128)), atol=1e-6)


def test_sine_encoding_hand_mask() -> None:
    mask = np.array([[[False, True, False], [False, False, False]]])  # 1 x 2 x 3
    pe = sine_position_encoding(mask)[0]  # 384 x 2 x 3, blocks (camera, y, x), each 64 sin then 64 cos
    two_pi, eps = 2 * math.pi, 1e-6
    # x counts along the row: [1, 1, 2] (the masked cell does not advance) / (2 + eps)
    x = [c / (2 + eps) * two_pi for c in (1, 1, 2)]
    np.testing.assert_allclose(pe[256, 0], [math.sin(v) for v in x], atol=1e-6)
    np.testing.assert_allclose(pe[320, 0], [math.cos(v) for v in x], atol=1e-6)
    # y counts down the columns; column 1 is [0, 1] / (1 + eps)
    np.testing.assert_allclose(pe[128, :, 1], [0.0, math.sin(1 / (1 + eps) * two_pi)], atol=1e-6)
    # frequency k = 2 divides by 10000 ** (2 / 128): the second sine of the y block
    y = 1 / (2 + eps) * two_pi
    assert abs(float(pe[129, 0, 0]) - math.sin(y / 10000 ** (2 / 128))) < 1e-6


def test_pos2posemb3d_order_is_y_x_z() -> None:
    emb = pos2posemb3d(torch.tensor([[0.1, 0.2, 0.3]]))[0]
    two_pi = 2 * math.pi
    expected = {
        0: math.sin(two_pi * 0.2),
        1: math.cos(two_pi * 0.2),
        2: math.sin(two_pi * 0.2 / 10000 ** (2 / 128)),
        128: math.sin(two_pi * 0.1),
        129: math.cos(two_pi * 0.1),
        256: math.sin(two_pi * 0.3),
    }
    for k, v in expected.items():
        assert abs(float(emb[k]) - v) < 1e-6, k


def test_reference_points_raw_for_queries_clamped_for_boxes(small_ckpt: dict[str, torch.Tensor]) -> None:
    model = _small_model(small_ckpt)
    head = model.pts_bbox_head
    raw = torch.tensor([1.5, -0.25, 0.5])
    with torch.no_grad():
        head.reference_points.weight[0] = raw
        head.refresh_embeddings()
        q_raw = head.query_embedding(pos2posemb3d(raw[None]))[0]
        q_clamped = head.query_embedding(pos2posemb3d(raw.clamp(0, 1)[None]))[0]
        torch.testing.assert_close(head.query_pos[0], q_raw)
        assert not torch.allclose(head.query_pos[0], q_clamped, atol=1e-3)
        o = torch.randn(1, SMALL.head.num_query, 256, generator=torch.Generator().manual_seed(2))
        _, preds = head.predict(o)
        reg = head.reg_branches[0](o)[0, 0]
    expected = [
        torch.sigmoid(reg[0] + LOGIT_MAX) * 96 - 48,
        torch.sigmoid(reg[1] - LOGIT_MAX) * 96 - 48,
        torch.sigmoid(reg[4] + 0.0) * 10 - 5,
    ]
    torch.testing.assert_close(preds[0, 0, [0, 1, 4]], torch.stack(expected), rtol=1e-5, atol=1e-4)
    torch.testing.assert_close(preds[0, 0, [2, 3, 5, 6, 7]], reg[[2, 3, 5, 6, 7]])


def _pred(x: float, y: float, z: float, dims: tuple[float, float, float], yaw: float) -> list[float]:
    theta = -yaw - math.pi / 2  # the official regression angle
    return [x, y, math.log(dims[0]), math.log(dims[1]), z, math.log(dims[2]), math.sin(theta), math.cos(theta)]


def test_decode_boxes_by_hand() -> None:
    preds = torch.tensor(
        [
            [
                _pred(1.0, 2.0, 0.5, (4.0, 2.0, 1.5), 0.3),
                _pred(-70.0, 5.0, -1.0, (1.0, 0.5, 1.8), -2.0),  # outside post_center_range
                _pred(10.0, -3.0, 2.0, (12.0, 3.0, 3.5), 3.0),
            ]
        ]
    )
    cls = torch.full((1, 3, 6), -9.0)
    cls[0, 2, 4], cls[0, 0, 1], cls[0, 2, 0] = 3.0, 2.0, 1.0
    out = decode_predictions(cls, preds, TopK(3))
    assert out["labels"].tolist() == [[4, 1, 0]]  # idx % 6
    torch.testing.assert_close(out["scores"], torch.sigmoid(torch.tensor([[3.0, 2.0, 1.0]])))
    expected = torch.tensor(
        [
            [10.0, -3.0, 2.0 - 3.5 / 2, 12.0, 3.0, 3.5, 3.0],  # query 2 = idx // 6
            [1.0, 2.0, 0.5 - 1.5 / 2, 4.0, 2.0, 1.5, 0.3],
            [10.0, -3.0, 2.0 - 3.5 / 2, 12.0, 3.0, 3.5, 3.0],
        ]
    )
    torch.testing.assert_close(out["boxes"][0], expected, rtol=1e-5, atol=1e-5)
    assert out["valid"].tolist() == [[True, True, True]]
    flagged = decode_predictions(
        torch.where(torch.arange(3)[None, :, None] == 1, 5.0, -9.0).expand(1, 3, 6), preds, TopK(2)
    )
    assert flagged["valid"].tolist() == [[False, False]]


@pytest.mark.parametrize("yaw", [0.0, 0.3, -2.0, math.pi / 2, 3.1, -3.1])
def test_yaw_from_sin_cos(yaw: float) -> None:
    preds = torch.tensor([[_pred(0.0, 0.0, 0.0, (1.0, 1.0, 1.0), yaw)]])
    out = decode_predictions(torch.zeros(1, 1, 6), preds, TopK(1))
    got = float(out["boxes"][0, 0, 6])
    assert -math.pi <= got < math.pi
    assert abs(math.remainder(got - yaw, 2 * math.pi)) < 1e-5


# -- configuration ------------------------------------------------------------------------------


def test_config_defaults_are_official() -> None:
    c = PETRConfig()
    assert c.class_names == ("Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist")
    assert c.preprocess.image_size == (800, 800) and c.preprocess.colour_order == "BGR" and not c.image.bgr_to_rgb
    assert c.image.mean == (123.675, 116.28, 103.53) and c.image.std == (58.395, 57.12, 57.375)
    c, top = c.head, c
    assert c.feature_size == (25, 100) and c.azimuth_range == (-math.radians(110), math.radians(110))
    assert c.elevation_range == (-math.pi / 4, math.pi / 4)
    assert (c.depth_num, c.depth_start, c.lid) == (64, 0.5, True)
    assert c.position_range == c.post_center_range == (-60, -60, -10, 60, 60, 10)
    assert c.point_cloud_range == (-48, -48, -5, 48, 48, 5)
    assert (c.num_query, c.embed_dims, c.num_heads, c.num_layers, c.ffn_dims) == (900, 256, 8, 6, 2048)
    assert (c.max_num, c.code_size, c.num_frustum_depths) == (300, 8, 96)
    assert PETRConfig.from_dict(top.to_dict()) == top


_CONFIG = """
import math
cam_fov = 220
classes = ['Car', 'Van', 'Truck', 'Bus', 'Pedestrian', 'Cyclist']
point_cloud_range = [-48, -48, -5, 48, 48, 5]
test_pipeline = [dict(type='LoadFisheye3DODMultiViewImageFromFiles', load_cam_names=[
    'fisheye_camera_front', 'fisheye_camera_left', 'fisheye_camera_right', 'fisheye_camera_rear'])]
model = dict(
    type='PETR',
    data_preprocessor=dict(mean=[123.675, 116.28, 103.53], std=[58.395, 57.12, 57.375], bgr_to_rgb=False),
    img_backbone=dict(type='mmdet.ResNet', depth=18, strides=(1, 2, 2, 2), dilations=(1, 1, 2, 4), out_indices=(2, 3)),
    img_neck=dict(type='mmdet.FPN', in_channels=[256, 512], out_channels=256, num_outs=2),
    pts_bbox_head=dict(
        type='HEAD_TYPE', num_classes=6, code_size=8, num_query=NUM_QUERY, LID=True, depth_start=0.5,
        position_range=[-60, -60, -10.0, 60, 60, 10.0], ocam_fov=cam_fov, feature_size=(25, 100),
        dbound=(0.5, 48.5, 0.5),
        azimuth_range=(-math.radians(cam_fov/2), math.radians(cam_fov/2)),
        elevation_range=(-math.pi/4, math.pi/4),
        transformer=dict(type='PETRTransformer', decoder=dict(
            type='PETRTransformerDecoder', return_intermediate=True, num_layers=6,
            transformerlayers=dict(
                attn_cfgs=[dict(type='MultiheadAttention', embed_dims=256, num_heads=8)] * 2,
                feedforward_channels=2048,
                operation_order=('self_attn', 'norm', 'cross_attn', 'norm', 'ffn', 'norm')))),
        bbox_coder=dict(type='NMSFreeCoder', post_center_range=[-60, -60, -10.0, 60, 60, 10.0],
                        pc_range=point_cloud_range, max_num=300, num_classes=6),
        positional_encoding=dict(type='SinePositionalEncoding3D', num_feats=128, normalize=True)))
"""


def test_from_mmdet3d_config(tmp_path) -> None:  # noqa: ANN001
    path = tmp_path / "fisheye_petr.py"
    path.write_text(_CONFIG.replace("HEAD_TYPE", "FisheyePETRHead").replace("NUM_QUERY", "900"))
    assert PETRConfig.from_mmdet3d_config(path) == PETRConfig()
    path.write_text(_CONFIG.replace("HEAD_TYPE", "FisheyePETRHead").replace("NUM_QUERY", "600"))
    assert PETRConfig.from_mmdet3d_config(path).head.num_query == 600
    path.write_text(_CONFIG.replace("HEAD_TYPE", "CylindricalPETRHead").replace("NUM_QUERY", "900"))
    with pytest.raises(ConfigError, match="CylindricalPETRHead"):
        PETRConfig.from_mmdet3d_config(path)


def test_unsupported_settings_are_refused() -> None:
    with pytest.raises(ConfigError, match="lid"):
        PETRConfig().replace(head={"lid": False})
    with pytest.raises(ConfigError, match="max_num"):
        PETRConfig().replace(head={"num_query": 10, "max_num": 300})
    assert (
        PETRConfig().replace(head={"num_query": 50, "max_num": 300}).head.max_num == 300
    )  # 50 * 6 = 300 candidates is enough
