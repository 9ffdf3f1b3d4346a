"""FisheyeBEVDet in plain PyTorch, loadable from the official Fisheye3DOD checkpoint by key.

Module names mirror the official model (``img_backbone``, ``img_neck``, ``view_transform``,
``pts_backbone``, ``pts_neck``, ``bbox_head``), so the checkpoint map is the identity except for the
view transform's geometry tables, which are checked against the rig and installed separately.

Input: uint8 BGR images B x N x H x W x 3 exactly as OpenCV decodes them; normalisation is in the
model (the RGB-ordered ImageNet statistics applied to the BGR channels, as the official
preprocessor does). Output: fixed-size tensors (boxes, scores, labels, valid) in the lidar frame.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch
from torch import nn

from fisheye_infer.artifact import OUTPUTS, RANKING_OUTPUTS
from fisheye_infer.errors import CheckpointError, ConfigError, FrameError
from fisheye_infer.geometry.tables import LSSParams

from .backbone import FPN, ResNet
from .bev_encoder import SECOND, SECONDFPN
from .checkpoint import GeometryReport, KeySpec, TableCheck, as_numpy, decide_geometry
from .config import BEVDetConfig
from .registry import register_model
from .synthetic import batchnorm_statistics, synthetic_images, temper_attention
from .transfusion import TransFusionHead
from .view_transform import FisheyeLSS, LSSGeometry

__all__ = ["FisheyeBEVDet", "checkpoint_filter_fn", "GEOMETRY_KEYS", "IGNORED_KEYS"]

_VT = "view_transform."
#: Official checkpoint keys holding geometry tables (not weights of this model).
GEOMETRY_KEYS = tuple(_VT + k for k in ("frustum", "sphere_grid_3d", "dx", "bx", "nx", "valid_fov_mask", "sphere_grid_2d"))
#: Keys an older code version may have saved; never used by the inference graph. At the released
#: commit (84a5bbd) they cannot occur: ``BaseFisheyeLSSTransform.__init__`` calls ``self.init_layer()``,
#: which dispatches to ``FisheyeLSSTransform.init_layer`` (depthnet only), so the base class's
#: ``proj_x`` is never built. Should a checkpoint still carry them, they are dropped with a warning.
IGNORED_KEYS = (_VT + "proj_x.weight", _VT + "proj_x.bias")
GRID_ATOL = 1e-5  # normalised grid units (~0.004 px on an 800 px image)
FRUSTUM_RTOL, FRUSTUM_ATOL = 0.0, 5e-5  # float32 linspace/trig of the official code: up to 7.6e-6 m at 48 m
BEV_ATOL = 1e-6


def checkpoint_filter_fn(state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Official key names -> this model's state dict: identity with the geometry (and proj_x) keys removed."""
    drop = set(GEOMETRY_KEYS) | set(IGNORED_KEYS)
    return {k: v for k, v in state_dict.items() if k not in drop}


CALIBRATION_FRAMES = 2
HEATMAP_PRIOR_LOGIT = -2.19
CALIBRATION_MAX_SIDE = 320  # backbone statistics barely depend on image size; keeps calibration fast


def calibrate(model: nn.Module, seed: int) -> None:
    """Collect BatchNorm statistics on seeded synthetic frames (image side capped for speed).

    The whole network is fully convolutional up to the angular grid, so smaller frames still
    exercise the full BEV grid and head with realistic statistics.
    """
    cfg: BEVDetConfig = model.config  # type: ignore[assignment]
    scale = min(1.0, CALIBRATION_MAX_SIDE / max(cfg.image.height, cfg.image.width))
    h = max(32, int(round(cfg.image.height * scale / 32)) * 32)
    w = max(32, int(round(cfg.image.width * scale / 32)) * 32)
    n = len(model.camera_names)  # type: ignore[arg-type]
    frames = [synthetic_images(seed * 1000 + i, 1, n, h, w) for i in range(CALIBRATION_FRAMES)]
    with batchnorm_statistics(model):
        for frame in frames:
            model.predict(frame)
    temper_attention(model, lambda: model.predict(frames[0]))
    _shape_box_heads(model, frames[0])
    # Heatmap logits: affine-map so the median cell sits at the official prior (-2.19, p = 0.1) and
    # the largest at about +0.8 (p = 0.69): peaks stay far from sigmoid saturation, where float32
    # would round neighbouring scores to the same value and create ties at the top-k boundary.
    with torch.no_grad():
        logits = model.predict(frames[0])["dense_heatmap"]
        median, top = logits.median(), logits.max()
        scale = 3.0 / float(max(top - median, 1e-3))
        final = model.bbox_head.heatmap_head[1]  # type: ignore[index]
        final.weight.mul_(scale)
        final.bias.mul_(scale).add_(HEATMAP_PRIOR_LOGIT - scale * float(median))


#: Target (mean, std) of the raw regression outputs of a trained head: centre offsets in cells,
#: gravity-centre height (m), log box sizes (l, w, h of a car-sized box), and sin/cos of yaw with
#: a norm near 1 (atan2 of a near-zero vector turns float32 rounding into large yaw errors; a
#: trained head predicts unit vectors, a random one does not unless told).
BOX_HEAD_TARGETS = {"center": ((0.0, 0.0), 0.3), "height": ((-0.8,), 0.4), "dim": ((1.4, 0.65, 0.45), 0.25), "rot": ((0.7, 0.7), 0.1)}


@torch.no_grad()
def _shape_box_heads(model: nn.Module, frame: torch.Tensor) -> None:
    """Affine-map each regression head's last layer so its outputs have a trained head's range.

    Random heads predict log-sizes of +-4 (boxes of 50 m): exp() then multiplies float32
    rounding by the box size, which a trained model never does.
    """
    head = model.bbox_head.prediction_heads[0]  # type: ignore[index]
    outputs = {}
    hooks = [getattr(head, name)[-1].register_forward_hook(lambda m, i, o, name=name: outputs.__setitem__(name, o))
             for name in BOX_HEAD_TARGETS]
    try:
        model.predict(frame)
    finally:
        for h in hooks:
            h.remove()
    for name, (means, std) in BOX_HEAD_TARGETS.items():
        final = getattr(head, name)[-1]
        out = outputs[name]  # B x C x P
        mu, sigma = out.mean(dim=(0, 2)), out.std(dim=(0, 2)).clamp(min=1e-6)
        gain = std / sigma
        final.weight.mul_(gain[:, None, None])
        final.bias.copy_((final.bias - mu) * gain + torch.tensor(means, dtype=final.bias.dtype))


@register_model("fisheye-bevdet", config_cls=BEVDetConfig, manifest="fisheye_bevdet_keys.json",
                calibrate=calibrate, ignored_keys=IGNORED_KEYS)
class FisheyeBEVDet(nn.Module):
    """Camera-only BEV detector: ResNet-18 + FPN, fisheye LSS, SECOND + SECONDFPN, TransFusion head."""

    def __init__(self, config: BEVDetConfig | None = None, rig: Any = None, geometry: LSSGeometry | None = None) -> None:
        super().__init__()
        self.config = cfg = config or BEVDetConfig()
        if geometry is None:
            if rig is None:
                from fisheye_infer.rig import default_rig

                rig = default_rig()
            if len(rig) != len(cfg.image.camera_names):
                raise ConfigError(f"the rig has {len(rig)} cameras ({', '.join(rig.names)}); the configuration "
                                  f"expects {len(cfg.image.camera_names)} ({', '.join(cfg.image.camera_names)})")
            geometry = LSSGeometry.from_rig(rig, cfg.view_transform)
        self.camera_names = tuple(rig.names) if rig is not None else tuple(cfg.image.camera_names)
        self.rig_geometry = geometry  # recomputed tables; the reference for checkpoint comparison
        img = cfg.image
        self.register_buffer("mean", torch.tensor(img.mean, dtype=torch.float32), persistent=False)
        self.register_buffer("std", torch.tensor(img.std, dtype=torch.float32), persistent=False)
        bb, vt, enc, hd = cfg.backbone, cfg.view_transform, cfg.bev_encoder, cfg.head
        self.img_backbone = ResNet(bb.depth, bb.strides, bb.dilations, bb.out_indices, base_channels=bb.base_channels)
        self.img_neck = FPN(bb.neck_in_channels, bb.neck_out_channels, bb.neck_num_outs)
        self.view_transform = FisheyeLSS(vt, geometry)
        self.pts_backbone = SECOND(enc.in_channels, enc.out_channels, enc.layer_nums, enc.layer_strides, enc.bn_eps)
        self.pts_neck = SECONDFPN(enc.fpn_in_channels, enc.fpn_out_channels, enc.upsample_strides,
                                  enc.use_conv_for_no_stride, enc.bn_eps)
        self.bbox_head = TransFusionHead(
            hd.in_channels, hd.hidden_channel, hd.num_classes, hd.num_proposals, hd.nms_kernel_size,
            hd.unsuppressed_classes, hd.num_decoder_layers, hd.num_heads, hd.ffn_channels,
            dict(hd.common_heads), hd.head_conv, hd.bev_size, hd.out_size_factor, hd.voxel_size,
            hd.pc_range, hd.post_center_range)
        self.eval()

    # -- forward --------------------------------------------------------------------------

    def normalise(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 B x N x H x W x 3 (BGR) -> float32 (B*N) x 3 x H x W, (x - mean[c]) / std[c], no channel swap."""
        x = (images.to(torch.float32) - self.mean) / self.std  # B x N x H x W x 3
        return x.flatten(0, 1).permute(0, 3, 1, 2)

    def extract_bev(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None,
                    tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Images -> B x C x X x Y BEV features (before SECOND)."""
        b, n = images.shape[0], images.shape[1]
        feats = self.img_neck(self.img_backbone(self.normalise(images)))
        p3 = feats[0]  # only FPN level 0 (stride 16) is used
        p3 = p3.reshape(b, n, p3.shape[1], p3.shape[2], p3.shape[3])
        return self.view_transform(p3, camera_valid, tables)

    def predict(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None,
                tables: dict[str, torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
        """Unvalidated pass returning every head output (also ``rot``, ``top_indices``, ``dense_heatmap``) and ``bev``.

        Image size is not checked here: the network is fully convolutional up to the angular grid,
        which synthetic-checkpoint calibration uses to run on smaller frames.
        """
        bev = self.extract_bev(images, camera_valid, tables)
        out = self.bbox_head(self.pts_neck(self.pts_backbone(bev)))
        out["bev"] = bev
        return out

    def forward_raw(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """The head's outputs before decoding (see ``TransFusionHead.forward_raw``): what training's losses read."""
        self._check_images(images, camera_valid)
        bev = self.extract_bev(images, camera_valid)
        return self.bbox_head.forward_raw(self.pts_neck(self.pts_backbone(bev)))

    def forward(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None,
                return_extras: bool = False, tables: dict[str, torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
        """images B x N x H x W x 3 (uint8 BGR), camera_valid B x N (1 = present) ->
        boxes B x P x 7 (x, y, z_bottom, l, w, h, yaw), scores B x P, labels B x P int64, valid B x P bool,
        and the ranking step's ``rank_scores`` / ``rank_indices`` (see ``models.ranking``).

        A camera with camera_valid = 0 contributes zero features to the BEV mean; cell counts stay
        those of the full rig (see ``FisheyeLSS.lift``).
        """
        self._check_images(images, camera_valid)
        out = self.predict(images, camera_valid, tables)
        if return_extras:
            return out
        return {k: out[k] for k in OUTPUTS + RANKING_OUTPUTS}

    def forward_dynamic(self, images: torch.Tensor, cam2lidar: torch.Tensor | np.ndarray,
                        camera_valid: torch.Tensor | None = None) -> dict[str, torch.Tensor]:
        """Per-sample extrinsics (B x N x 4 x 4) instead of the baked rig, for parity on dataset frames.

        Pools with ``index_add_`` per sample (reference speed, not exportable). The intrinsic grid
        and frustum stay this model's.
        """
        self._check_images(images, camera_valid)
        b, n = images.shape[0], images.shape[1]
        feats = self.img_neck(self.img_backbone(self.normalise(images)))
        p3 = feats[0].reshape(b, n, *feats[0].shape[1:])
        bev = self.view_transform.forward_dynamic(p3, cam2lidar, camera_valid)
        out = self.bbox_head(self.pts_neck(self.pts_backbone(bev)))
        return {k: out[k] for k in OUTPUTS + RANKING_OUTPUTS}

    def _check_images(self, images: torch.Tensor, camera_valid: torch.Tensor | None) -> None:
        n = len(self.camera_names)
        h, w = self.config.image.height, self.config.image.width
        if images.dim() != 5 or tuple(images.shape[1:]) != (n, h, w, 3):
            raise FrameError(f"images: expected (B, {n}, {h}, {w}, 3) BGR, got {tuple(images.shape)}")
        if camera_valid is not None and tuple(camera_valid.shape) != (images.shape[0], n):
            raise FrameError(f"camera_valid: expected ({images.shape[0]}, {n}), got {tuple(camera_valid.shape)}")

    def geometry_tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables the exported graph holds as named initializers."""
        return self.view_transform.tables()

    def geometry_params(self) -> LSSParams:
        """The parameters that define the geometry tables (what a re-baked file recomputes them from)."""
        vt = self.config.view_transform
        return LSSParams(feature_size=tuple(vt.feature_size), azimuth_range=tuple(vt.azimuth_range),
                         elevation_range=tuple(vt.elevation_range), dbound=tuple(vt.dbound), xbound=tuple(vt.xbound),
                         ybound=tuple(vt.ybound), zbound=tuple(vt.zbound),
                         bucket_sizes=tuple(self.view_transform.geometry.plan.bucket_sizes))

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        vt = self.config.view_transform
        h, w = vt.feature_size
        d = vt.num_depth_bins
        f32 = torch.float32
        return {_VT + "frustum": ((d, h, w, 3), f32), _VT + "sphere_grid_3d": ((d, h, w, 3), f32),
                _VT + "dx": ((3,), f32), _VT + "bx": ((3,), f32), _VT + "nx": ((3,), torch.int64),
                _VT + "valid_fov_mask": ((1, 1, h, w), f32), _VT + "sphere_grid_2d": ((h, w, 2), f32)}

    def official_keys(self) -> dict[str, KeySpec]:
        """All official keys in checkpoint order: weights, with the geometry tables before depthnet."""
        out: dict[str, KeySpec] = {}
        for key, value in self.state_dict().items():
            if key == _VT + "depthnet.weight":
                out.update(self.official_geometry_specs())
            out[key] = (tuple(value.shape), value.dtype)
        return out

    def checkpoint_filter_fn(self, state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return checkpoint_filter_fn(state_dict)

    def official_geometry_state(self) -> dict[str, torch.Tensor]:
        """The geometry tables in official form, as an official checkpoint stores them."""
        g = self.view_transform.geometry
        d = g.frustum.shape[0]
        grid3d = np.concatenate([np.broadcast_to(g.grid, (d, *g.grid.shape)),
                                 np.zeros((d, *g.grid.shape[:2], 1), np.float32)], axis=-1)
        t = torch.from_numpy
        return {_VT + "frustum": t(g.frustum.copy()), _VT + "sphere_grid_3d": t(np.ascontiguousarray(grid3d)),
                _VT + "dx": t(g.bev_grid.dx.copy()), _VT + "bx": t(g.bev_grid.bx.copy()),
                _VT + "nx": torch.tensor(g.bev_grid.nx, dtype=torch.int64),
                _VT + "valid_fov_mask": t(g.valid_fov_mask.copy()), _VT + "sphere_grid_2d": t(g.grid.copy())}

    def official_state_dict(self) -> dict[str, torch.Tensor]:
        """This model's weights and geometry under the official names, in official order."""
        weights = self.state_dict()
        geometry = self.official_geometry_state()
        return {k: (geometry[k] if k in geometry else weights[k]).detach().clone() for k in self.official_keys()}

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Compare the stored tables with the rig's and install the ones ``policy`` selects."""
        ref = self.rig_geometry
        bev = ref.bev_grid
        hard = [TableCheck(_VT + "dx", as_numpy(state_dict[_VT + "dx"]), bev.dx, atol=BEV_ATOL),
                TableCheck(_VT + "bx", as_numpy(state_dict[_VT + "bx"]), bev.bx, atol=BEV_ATOL),
                TableCheck(_VT + "nx", as_numpy(state_dict[_VT + "nx"]), np.array(bev.nx))]
        bad = [c for c in hard if not c.agrees]
        if bad:
            raise CheckpointError("the checkpoint's BEV grid differs from the configuration's (xbound/ybound/zbound): "
                                  + "; ".join(c.describe() for c in bad))
        grid2d = as_numpy(state_dict[_VT + "sphere_grid_2d"])
        grid3d = as_numpy(state_dict[_VT + "sphere_grid_3d"])
        frustum = as_numpy(state_dict[_VT + "frustum"])
        # Only slice 0 of sphere_grid_3d is ever used (it is sphere_grid_2d); in the other slices
        # float32 noise flips the two horizon rays at exactly +-110 degrees to the out-of-fov sentinel.
        checks = (TableCheck(_VT + "sphere_grid_2d", grid2d, ref.grid, atol=GRID_ATOL),
                  TableCheck(_VT + "sphere_grid_3d[0]", grid3d[0, ..., :2], ref.grid, atol=GRID_ATOL),
                  TableCheck(_VT + "frustum", frustum, ref.frustum, atol=FRUSTUM_ATOL, rtol=FRUSTUM_RTOL))
        source = decide_geometry(checks, policy, context="FisheyeBEVDet checkpoint")
        geometry = ref.with_tables(grid=grid2d, frustum=frustum) if source == "checkpoint" else ref
        self.set_geometry(geometry)
        return GeometryReport(source, checks + tuple(hard))

    def set_geometry(self, geometry: LSSGeometry) -> None:
        """Install other geometry tables (same configuration), keeping the device of the weights."""
        device = self.view_transform.depthnet.weight.device
        self.view_transform.set_geometry(geometry)
        self.view_transform.to(device)
