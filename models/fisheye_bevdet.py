"""FisheyeBEVDet in plain PyTorch, loadable from the official Fisheye3DOD checkpoint by key.

Module names mirror the official model (``img_backbone``, ``img_neck``, ``view_transform``,
``pts_backbone``, ``pts_neck``, ``bbox_head``), so the checkpoint map is the identity except for the
view transform's geometry tables, which are checked against the rig and installed separately.

Input: uint8 BGR images B x N x H x W x 3 exactly as OpenCV decodes them; normalisation is in the
model (the RGB-ordered ImageNet statistics applied to the BGR channels, as the official
preprocessor does). Output: fixed-size tensors (boxes, scores, labels, valid) in the lidar frame.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import torch

from fisheye_infer.errors import CheckpointError
from fisheye_infer.geometry.lss import LSSGeometry
from fisheye_infer.geometry.pooling import BevGrid
from fisheye_infer.runtime.artifact import OUTPUTS, RANKING_OUTPUTS

from .backbone import FPN, ResNet
from .base import FisheyeDetector
from .bev_encoder import SECOND, SECONDFPN
from .bevdet_config import BEVDetConfig, ViewTransformConfig
from .checkpoint import GeometryReport, KeySpec, TableCheck, as_numpy, decide_geometry, warn_of_other_lenses
from .normalise import normalise_frames
from .registry import register_model
from .transfusion import INT8_FLOAT, SCORE_SEMANTICS, TransFusionHead
from .view_transform import AnyLSSGeometry, FisheyeLSS

__all__ = [
    "FisheyeBEVDet",
    "checkpoint_filter_fn",
    "bev_grid_checks",
    "GEOMETRY_KEYS",
    "IGNORED_KEYS",
    "SIGNATURE_KEYS",
]

_VT = "view_transform."
#: Official checkpoint keys holding geometry tables (not weights of this model).
GEOMETRY_KEYS = tuple(
    _VT + k for k in ("frustum", "sphere_grid_3d", "dx", "bx", "nx", "valid_fov_mask", "sphere_grid_2d")
)
#: Keys an older code version may have saved; never used by the inference graph. At the released
#: commit (84a5bbd) they cannot occur: ``BaseFisheyeLSSTransform.__init__`` calls ``self.init_layer()``,
#: which dispatches to ``FisheyeLSSTransform.init_layer`` (depthnet only), so the base class's
#: ``proj_x`` is never built. Should a checkpoint still carry them, they are dropped with a warning.
IGNORED_KEYS = (_VT + "proj_x.weight", _VT + "proj_x.bias")
#: Keys every FisheyeBEVDet-family checkpoint holds; the spherical one also ``sphere_grid_2d``.
SIGNATURE_KEYS = (_VT + "depthnet.weight", "bbox_head.heatmap_head.1.weight")
GRID_ATOL = 1e-5  # normalised grid units (~0.004 px on an 800 px image)
FRUSTUM_RTOL, FRUSTUM_ATOL = 0.0, 5e-5  # float32 linspace/trig of the official code: up to 7.6e-6 m at 48 m
BEV_ATOL = 1e-6


def checkpoint_filter_fn(state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Official key names -> this model's state dict: identity with the geometry (and proj_x) keys removed."""
    drop = set(GEOMETRY_KEYS) | set(IGNORED_KEYS)
    return {k: v for k, v in state_dict.items() if k not in drop}


def bev_grid_checks(state_dict: Mapping[str, torch.Tensor], bev: BevGrid) -> tuple[TableCheck, ...]:
    """dx, bx, nx must equal the configuration's grid whatever the policy: they size the BEV tensor."""
    hard = (
        TableCheck(_VT + "dx", as_numpy(state_dict[_VT + "dx"]), bev.dx, atol=BEV_ATOL),
        TableCheck(_VT + "bx", as_numpy(state_dict[_VT + "bx"]), bev.bx, atol=BEV_ATOL),
        TableCheck(_VT + "nx", as_numpy(state_dict[_VT + "nx"]), np.array(bev.nx)),
    )
    bad = [c for c in hard if not c.agrees]
    if bad:
        raise CheckpointError(
            "the checkpoint's BEV grid differs from the configuration's (xbound/ybound/zbound): "
            + "; ".join(c.describe() for c in bad)
        )
    return hard


@register_model(
    "fisheye-bevdet",
    manifest="fisheye_bevdet_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=(*SIGNATURE_KEYS, _VT + "sphere_grid_2d"),
    ignored_keys=IGNORED_KEYS,
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
)
class FisheyeBEVDet(FisheyeDetector):
    """Camera-only BEV detector: ResNet-18 + FPN, fisheye LSS, SECOND + SECONDFPN, TransFusion head."""

    config_cls: ClassVar[type[BEVDetConfig]] = BEVDetConfig
    config: BEVDetConfig
    rig_geometry: AnyLSSGeometry  # what geometry_from_rig makes of the configuration's LSS parameters
    mean: torch.Tensor  # (3,) buffers
    std: torch.Tensor

    def __init__(
        self, config: BEVDetConfig | None = None, rig: Any = None, geometry: AnyLSSGeometry | None = None
    ) -> None:
        super().__init__(config, rig, geometry)
        cfg = self.config
        img = cfg.image
        self.register_buffer("mean", torch.tensor(img.mean, dtype=torch.float32), persistent=False)
        self.register_buffer("std", torch.tensor(img.std, dtype=torch.float32), persistent=False)
        bb, vt, enc, hd = cfg.backbone, cfg.view_transform, cfg.bev_encoder, cfg.head
        self.img_backbone = ResNet(bb.depth, bb.strides, bb.dilations, bb.out_indices, base_channels=bb.base_channels)
        self.img_neck = FPN(bb.neck_in_channels, bb.neck_out_channels, bb.neck_num_outs)
        self.view_transform = self._build_view_transform(vt, self.rig_geometry)
        self.pts_backbone = SECOND(enc.in_channels, enc.out_channels, enc.layer_nums, enc.layer_strides, enc.bn_eps)
        self.pts_neck = SECONDFPN(
            enc.fpn_in_channels, enc.fpn_out_channels, enc.upsample_strides, enc.use_conv_for_no_stride, enc.bn_eps
        )
        self.bbox_head = TransFusionHead(
            hd.in_channels,
            hd.hidden_channel,
            hd.num_classes,
            hd.num_proposals,
            hd.nms_kernel_size,
            hd.unsuppressed_classes,
            hd.num_decoder_layers,
            hd.num_heads,
            hd.ffn_channels,
            dict(hd.common_heads),
            hd.head_conv,
            hd.bev_size,
            hd.out_size_factor,
            hd.voxel_size,
            hd.pc_range,
            hd.post_center_range,
        )
        self.eval()

    def _build_view_transform(self, cfg: ViewTransformConfig, geometry: Any) -> FisheyeLSS:
        """The view transform module (the cylindrical baseline builds its own)."""
        return FisheyeLSS(cfg, geometry)

    # -- stages (see ``FisheyeDetector``) ---------------------------------------------------

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 (BGR) -> float32 (B*N) x 3 x H x W, (x - mean[c]) / std[c], no channel swap
        (see ``normalise_frames`` for where each step runs); no front end, so ``tables`` is not read."""
        return normalise_frames(images, self.mean, self.std)

    def scene_features(
        self,
        feats: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
        cam2lidar: Any = None,
    ) -> torch.Tensor:
        """Image features B x V x C x h x w -> B x C x X x Y BEV features (before SECOND), by the view transform.

        With ``cam2lidar`` the view transform pools per sample with ``index_add_`` (reference speed,
        not exportable); the intrinsic grid and frustum stay this model's.
        """
        if cam2lidar is not None:
            return self.view_transform.forward_dynamic(feats, cam2lidar, camera_valid)
        return self.view_transform(feats, camera_valid, tables)

    def head_outputs(self, scene: torch.Tensor) -> dict[str, torch.Tensor]:
        """BEV features -> every head output (also ``rot``, ``top_indices``, ``dense_heatmap``) and ``bev`` itself."""
        out: dict[str, torch.Tensor] = self.bbox_head(self.pts_neck(self.pts_backbone(scene)))
        out["bev"] = scene
        return out

    def extract_bev(
        self,
        images: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """Deprecated: ``scene_features(image_features(images, tables), camera_valid, tables)``."""
        self._deprecated("extract_bev", "scene_features(image_features(images))")
        tables = tables or self.geometry_tables()
        feats = self.image_features(images, tables)
        return self.scene_features(feats, self.view_valid(camera_valid, feats.shape[1]), tables)

    def forward_raw(
        self,
        images: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
    ) -> dict[str, torch.Tensor]:
        """The head's outputs before decoding (see ``TransFusionHead.forward_raw``): what training's losses read.
        ``tables`` replaces installed geometry tables by name (a training step's moved lenses)."""
        self._check_images(images, camera_valid)
        tables = {**self.view_transform.tables(), **tables} if tables else None
        feats = self.image_features(images, tables)
        bev = self.scene_features(feats, self.view_valid(camera_valid, feats.shape[1]), tables)
        raw: dict[str, torch.Tensor] = self.bbox_head.forward_raw(self.pts_neck(self.pts_backbone(bev)))
        return raw

    def forward(
        self,
        images: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        return_extras: bool = False,
        tables: dict[str, torch.Tensor] | None = None,
    ) -> dict[str, torch.Tensor]:
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

    def forward_dynamic(
        self, images: torch.Tensor, cam2lidar: torch.Tensor | np.ndarray, camera_valid: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        """Per-sample extrinsics (B x N x 4 x 4) instead of the baked rig, for parity on dataset frames.

        Pools with ``index_add_`` per sample (reference speed, not exportable). The intrinsic grid
        and frustum stay this model's.
        """
        self._check_images(images, camera_valid)
        out = self.predict(images, camera_valid, cam2lidar=cam2lidar)
        return {k: out[k] for k in OUTPUTS + RANKING_OUTPUTS}

    def geometry_tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables the exported graph holds as named initializers."""
        return self.view_transform.tables()

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        vt = self.config.view_transform
        h, w = vt.feature_size
        d = vt.num_depth_bins
        f32 = torch.float32
        return {
            _VT + "frustum": ((d, h, w, 3), f32),
            _VT + "sphere_grid_3d": ((d, h, w, 3), f32),
            _VT + "dx": ((3,), f32),
            _VT + "bx": ((3,), f32),
            _VT + "nx": ((3,), torch.int64),
            _VT + "valid_fov_mask": ((1, 1, h, w), f32),
            _VT + "sphere_grid_2d": ((h, w, 2), f32),
        }

    def official_keys(self) -> dict[str, KeySpec]:
        """All official keys in checkpoint order: weights, with the geometry tables before depthnet."""
        out: dict[str, KeySpec] = {}
        for key, value in self.state_dict().items():
            if key == _VT + "depthnet.weight":
                out.update(self.official_geometry_specs())
            out[key] = (tuple(value.shape), value.dtype)
        return out

    def official_geometry_state(self) -> dict[str, torch.Tensor]:
        """The geometry tables in official form, as an official checkpoint stores them: one grid and one mask,
        the first camera's (the official rig's cameras share one lens)."""
        g = self.view_transform.geometry
        assert isinstance(g, LSSGeometry)  # FrustumBEVDet overrides this for its geometries
        d, grid = g.frustum.shape[0], g.grid[0]
        grid3d = np.concatenate(
            [np.broadcast_to(grid, (d, *grid.shape)), np.zeros((d, *grid.shape[:2], 1), np.float32)], axis=-1
        )
        t = torch.from_numpy
        return {
            _VT + "frustum": t(g.frustum.copy()),
            _VT + "sphere_grid_3d": t(np.ascontiguousarray(grid3d)),
            _VT + "dx": t(g.bev_grid.dx.copy()),
            _VT + "bx": t(g.bev_grid.bx.copy()),
            _VT + "nx": torch.tensor(g.bev_grid.nx, dtype=torch.int64),
            _VT + "valid_fov_mask": t(g.valid_fov_mask[:1].copy()),
            _VT + "sphere_grid_2d": t(grid.copy()),
        }

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Compare the stored tables with the rig's (its grid with the first camera's) and install the ones
        ``policy`` selects."""
        ref = self.rig_geometry
        assert isinstance(ref, LSSGeometry)  # FrustumBEVDet overrides this for its geometries
        hard = bev_grid_checks(state_dict, ref.bev_grid)
        grid2d = as_numpy(state_dict[_VT + "sphere_grid_2d"])
        grid3d = as_numpy(state_dict[_VT + "sphere_grid_3d"])
        frustum = as_numpy(state_dict[_VT + "frustum"])
        # Only slice 0 of sphere_grid_3d is ever used (it is sphere_grid_2d); in the other slices
        # float32 noise flips the two horizon rays at exactly +-110 degrees to the out-of-fov sentinel.
        checks = (
            TableCheck(_VT + "sphere_grid_2d", grid2d, ref.grid[0], atol=GRID_ATOL),
            TableCheck(_VT + "sphere_grid_3d[0]", grid3d[0, ..., :2], ref.grid[0], atol=GRID_ATOL),
            TableCheck(_VT + "frustum", frustum, ref.frustum, atol=FRUSTUM_ATOL, rtol=FRUSTUM_RTOL),
        )
        source = decide_geometry(checks, policy, context="FisheyeBEVDet checkpoint")
        warn_of_other_lenses("FisheyeBEVDet checkpoint", self.camera_names, ref.grid, policy)
        geometry = ref.with_tables(grid=grid2d, frustum=frustum) if source == "checkpoint" else ref
        self.set_geometry(geometry)
        return GeometryReport(source, checks + hard)

    def set_geometry(self, geometry: AnyLSSGeometry) -> None:
        """Install other geometry tables (same configuration), keeping the device of the weights."""
        device = self.view_transform.depthnet.weight.device
        self.view_transform.set_geometry(geometry)
        self.view_transform.to(device)
