"""FisheyeBEVDet on cylindrical images (``configs/fisheye_to_cyl_bevdet.py``) in plain PyTorch.

    model = create_model("fisheye-bevdet-cyl")                 # released geometry (see below)
    model, report = load_model("fisheye-bevdet-cyl", "cyl_bevdet.pth")
    out = model(images_uint8)                                  # B x 4 x 800 x 800 x 3 raw fisheye BGR

The official pipeline rectifies each raw fisheye image onto a 400 x 800 cylinder with cv2.remap
before normalisation; here that is the first op of the graph (``geom.image_grid``), so an exported
model takes raw uint8 fisheye frames like FisheyeBEVDet. After it: the same ResNet-18 + FPN (P3
25 x 50), a ``CylindricalLSS`` (depthnet directly on P3, cylindrical frustum, the same trunc mean
pool through the bucketed plan), SECOND + SECONDFPN and TransFusion. Module names are the official
ones, so the checkpoint map is the identity apart from the view transform's geometry keys
(``frustum``, ``dx``, ``bx``, ``nx``), which are checked against the rig and installed separately.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np
import torch
from torch import nn

from fisheye_infer.errors import CheckpointError, ConfigError
from fisheye_infer.geometry.pooling import BevGrid
from fisheye_infer.geometry.tables import CylLSSParams

from .backbone import FPN, ResNet
from .bev_encoder import SECOND, SECONDFPN
from .checkpoint import GeometryReport, KeySpec, TableCheck, as_numpy, decide_geometry
from .cyl_config import BEVDetCylConfig
from .cyl_view_transform import CylindricalLSS, CylLSSGeometry
from .cylindrical import check_rig_image_size, rectify
from .fisheye_bevdet import FisheyeBEVDet, calibrate
from .registry import register_model
from .transfusion import TransFusionHead

__all__ = ["FisheyeBEVDetCyl", "checkpoint_filter_fn", "GEOMETRY_KEYS", "lss_params"]

_VT = "view_transform."
#: Official checkpoint keys holding geometry tables (not weights of this model), in official order.
GEOMETRY_KEYS = tuple(_VT + k for k in ("frustum", "dx", "bx", "nx"))
BEV_ATOL = 1e-6
# The official frustum is float32 torch arithmetic on float32 linspace angles. Taken literally the
# released ranges span +-110 rad, where one float32 ulp of the angle is 7.6e-6 rad, i.e. 0.4 mm at
# 48.5 m; other ranges move points by metres.
FRUSTUM_ATOL = 2e-3


def checkpoint_filter_fn(state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Official key names -> this model's state dict: identity with the geometry keys removed."""
    return {k: v for k, v in state_dict.items() if k not in GEOMETRY_KEYS}


def lss_params(cfg: BEVDetCylConfig) -> CylLSSParams:
    """The parameters of the model's geometry tables (what an exported file records and re-baking reads)."""
    vt = cfg.view_transform
    return CylLSSParams(feature_size=tuple(vt.feature_size), azimuth_range=tuple(vt.azimuth_range),
                        elevation_range=tuple(vt.elevation_range), image_size=(cfg.cylinder.height, cfg.cylinder.width),
                        dbound=tuple(vt.dbound), xbound=tuple(vt.xbound), ybound=tuple(vt.ybound), zbound=tuple(vt.zbound))


@register_model("fisheye-bevdet-cyl", config_cls=BEVDetCylConfig, manifest="fisheye_bevdet_cyl_keys.json",
                calibrate=calibrate)
class FisheyeBEVDetCyl(FisheyeBEVDet):
    """Cylindrical-image BEV detector: rectification, ResNet-18 + FPN, cylindrical LSS, SECOND, TransFusion.

    Degrees as radians: the released config passes ``horizontal_range=[-110, 110]`` and
    ``vertical_range=[-45, 45]`` (degrees) to code that uses them as radians, both in the image
    rectification and in the frustum. The configuration's ``view_transform.azimuth_range`` /
    ``elevation_range`` are taken as radians exactly as written, so the default configuration and
    ``BEVDetCylConfig.from_mmdet3d_config`` of the released file reproduce that geometry (azimuth
    over +-110 rad, about 35 turns, 0.2753 rad per image column; heights +-tan(45 rad) = +-1.6197752;
    every ray more than 110 degrees off-axis black). Writing ``math.radians(110)`` /
    ``math.radians(45)`` in the config gives the intended geometry. The checkpoint's stored frustum
    records which of the two it was trained with: under ``geometry="verify"`` a mismatch is refused
    with the frustum named.

    The rectification grid is not stored in checkpoints (the pipeline computed it from the
    calibration file), so it always comes from the rig. Methods other than construction, the
    preprocessing and the geometry keys are FisheyeBEVDet's.
    """

    def __init__(self, config: BEVDetCylConfig | None = None, rig: Any = None,
                 geometry: CylLSSGeometry | None = None) -> None:
        # FisheyeBEVDet.__init__ builds the spherical view transform; the layers are built here
        # with the same names and order instead.
        nn.Module.__init__(self)
        self.config = cfg = config or BEVDetCylConfig()  # type: ignore[assignment]
        if geometry is None:
            if rig is None:
                from fisheye_infer.rig import default_rig

                rig = default_rig()
            if len(rig) != len(cfg.image.camera_names):
                raise ConfigError(f"the rig has {len(rig)} cameras ({', '.join(rig.names)}); the configuration "
                                  f"expects {len(cfg.image.camera_names)} ({', '.join(cfg.image.camera_names)})")
            check_rig_image_size(rig, cfg.image.height, cfg.image.width, "image.height/width")
            geometry = CylLSSGeometry.from_rig(rig, lss_params(cfg))
        self.camera_names = tuple(rig.names) if rig is not None else tuple(cfg.image.camera_names)
        self.rig_geometry = geometry  # type: ignore[assignment]  # recomputed tables; the checkpoint reference
        img = cfg.image
        self.register_buffer("mean", torch.tensor(img.mean, dtype=torch.float32), persistent=False)
        self.register_buffer("std", torch.tensor(img.std, dtype=torch.float32), persistent=False)
        bb, vt, enc, hd = cfg.backbone, cfg.view_transform, cfg.bev_encoder, cfg.head
        self.img_backbone = ResNet(bb.depth, bb.strides, bb.dilations, bb.out_indices, base_channels=bb.base_channels)
        self.img_neck = FPN(bb.neck_in_channels, bb.neck_out_channels, bb.neck_num_outs)
        self.view_transform = CylindricalLSS(vt, geometry)
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

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw fisheye (BGR) -> float32 (B*N) x 3 x Hc x Wc normalised cylinder images.

        Rectification runs on raw pixel values, normalisation after it, as in the official pipeline.
        """
        grid = (tables or self.geometry_tables())["geom.image_grid"]
        x = rectify(images, grid)  # B x N x 3 x Hc x Wc
        x = (x - self.mean.reshape(1, 1, 3, 1, 1)) / self.std.reshape(1, 1, 3, 1, 1)
        return x.flatten(0, 1)

    def extract_bev(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None,
                    tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Raw images -> B x C x X x Y BEV features (before SECOND); frames of any size are rectified
        to the configured cylinder (synthetic-checkpoint calibration uses smaller ones)."""
        b, n = images.shape[0], images.shape[1]
        tables = tables or self.geometry_tables()
        p3 = self.img_neck(self.img_backbone(self.normalise(images, tables)))[0]  # FPN level 0 only
        return self.view_transform(p3.reshape(b, n, *p3.shape[1:]), camera_valid, tables)

    def geometry_params(self) -> CylLSSParams:
        """The parameters of this model's ``geom.*`` tables."""
        return lss_params(self.config)  # type: ignore[arg-type]

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        vt = self.config.view_transform
        h, w = vt.feature_size
        f32 = torch.float32
        return {_VT + "frustum": ((vt.num_depth_bins, h, w, 3), f32), _VT + "dx": ((3,), f32),
                _VT + "bx": ((3,), f32), _VT + "nx": ((3,), torch.int64)}

    def checkpoint_filter_fn(self, state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return checkpoint_filter_fn(state_dict)

    def official_geometry_state(self) -> dict[str, torch.Tensor]:
        """The geometry tables in official form, as an official checkpoint stores them."""
        g = self.view_transform.geometry
        bev = g.bev_grid
        t = torch.from_numpy
        return {_VT + "frustum": t(g.frustum.copy()), _VT + "dx": t(bev.dx.copy()), _VT + "bx": t(bev.bx.copy()),
                _VT + "nx": torch.tensor(bev.nx, dtype=torch.int64)}

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Compare the stored frustum and BEV grid with the rig's and install what ``policy`` selects."""
        ref: CylLSSGeometry = self.rig_geometry  # type: ignore[assignment]
        hard = _bev_grid_checks(state_dict, ref.bev_grid)
        frustum = as_numpy(state_dict[_VT + "frustum"])
        checks = (TableCheck(_VT + "frustum", frustum, ref.frustum, atol=FRUSTUM_ATOL),)
        source = decide_geometry(checks, policy, context="FisheyeBEVDet-cyl checkpoint")
        geometry = ref.with_tables(frustum=frustum) if source == "checkpoint" else ref
        self.set_geometry(geometry)  # type: ignore[arg-type]
        return GeometryReport(source, checks + hard)


def _bev_grid_checks(state_dict: Mapping[str, torch.Tensor], bev: BevGrid) -> tuple[TableCheck, ...]:
    """dx, bx, nx must equal the configuration's grid whatever the policy: they size the BEV tensor."""
    hard = (TableCheck(_VT + "dx", as_numpy(state_dict[_VT + "dx"]), bev.dx, atol=BEV_ATOL),
            TableCheck(_VT + "bx", as_numpy(state_dict[_VT + "bx"]), bev.bx, atol=BEV_ATOL),
            TableCheck(_VT + "nx", as_numpy(state_dict[_VT + "nx"]), np.array(bev.nx)))
    bad = [c for c in hard if not c.agrees]
    if bad:
        raise CheckpointError("the checkpoint's BEV grid differs from the configuration's (xbound/ybound/zbound): "
                              + "; ".join(c.describe() for c in bad))
    return hard
