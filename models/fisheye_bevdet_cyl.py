"""FisheyeBEVDet on cylindrical images (``configs/fisheye_to_cyl_bevdet.py``) in plain PyTorch.

    model = create_model("fisheye-bevdet-cyl")                 # released geometry (see below)
    model, report = load_model("fisheye-bevdet-cyl", "cyl_bevdet.pth")
    out = model(images_uint8)                                  # B x 4 x 800 x 800 x 3 raw fisheye BGR

The official pipeline rectifies each raw fisheye image onto a 400 x 800 cylinder with cv2.remap
before normalisation; here that is the first op of the graph (``geom.rectify.*``), so an exported
model takes raw uint8 fisheye frames like FisheyeBEVDet. After it: the same ResNet-18 + FPN (P3
25 x 50), a ``CylindricalLSS`` (depthnet directly on P3, cylindrical frustum, the same trunc mean
pool through the bucketed plan), SECOND + SECONDFPN and TransFusion. Module names are the official
ones, so the checkpoint map is the identity apart from the view transform's geometry keys
(``frustum``, ``dx``, ``bx``, ``nx``), which are checked against the rig and installed separately.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import torch

from fisheye_infer.geometry.cyl_lss import CylLSSGeometry
from fisheye_infer.geometry.tables import RECTIFY
from fisheye_infer.rig import Rig

from .checkpoint import GeometryReport, KeySpec, TableCheck, as_numpy, decide_geometry
from .cyl_config import BEVDetCylConfig, CylViewTransformConfig
from .cylindrical import check_rig_image_size, rectify
from .fisheye_bevdet import SIGNATURE_KEYS, FisheyeBEVDet, bev_grid_checks
from .registry import register_model
from .resample import taps_for
from .transfusion import INT8_FLOAT, SCORE_SEMANTICS
from .view_transform import CylindricalLSS

__all__ = ["FisheyeBEVDetCyl", "checkpoint_filter_fn", "GEOMETRY_KEYS"]

_VT = "view_transform."
#: Official checkpoint keys holding geometry tables (not weights of this model), in official order.
GEOMETRY_KEYS = tuple(_VT + k for k in ("frustum", "dx", "bx", "nx"))
# The official frustum is float32 torch arithmetic on float32 linspace angles. Taken literally the
# released ranges span +-110 rad, where one float32 ulp of the angle is 7.6e-6 rad, i.e. 0.4 mm at
# 48.5 m; other ranges move points by metres.
FRUSTUM_ATOL = 2e-3


def checkpoint_filter_fn(state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Official key names -> this model's state dict: identity with the geometry keys removed."""
    return {k: v for k, v in state_dict.items() if k not in GEOMETRY_KEYS}


@register_model("fisheye-bevdet-cyl", manifest="fisheye_bevdet_cyl_keys.json", checkpoint_filter=checkpoint_filter_fn,
                signature_keys=SIGNATURE_KEYS, absent_keys=(_VT + "sphere_grid_2d",), score_semantics=SCORE_SEMANTICS,
                int8_float=INT8_FLOAT)
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
    calibration file), so it always comes from the rig. Methods other than the view transform, the
    preprocessing and the geometry keys are FisheyeBEVDet's.
    """

    config_cls = BEVDetCylConfig
    config: BEVDetCylConfig

    def _check_rig(self, rig: Rig) -> None:
        check_rig_image_size(rig, self.config.image.height, self.config.image.width, "image.height/width")

    def _build_view_transform(self, cfg: CylViewTransformConfig, geometry: Any) -> CylindricalLSS:  # type: ignore[override]
        return CylindricalLSS(cfg, geometry)

    # -- forward --------------------------------------------------------------------------

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw fisheye (BGR) -> float32 (B*N) x 3 x Hc x Wc normalised cylinder images.

        Rectification runs on raw pixel values, normalisation after it, as in the official pipeline.
        """
        g = self.view_transform.geometry
        index, weight = taps_for(tables or self.geometry_tables(), RECTIFY, g.image_grid, g.params.source_size,  # type: ignore[union-attr]
                                 images.shape[2:4], images.device)
        x = rectify(images, index, weight, g.params.image_size)  # type: ignore[union-attr]  # B x N x 3 x Hc x Wc
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

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        vt = self.config.view_transform
        h, w = vt.feature_size
        f32 = torch.float32
        return {_VT + "frustum": ((vt.num_depth_bins, h, w, 3), f32), _VT + "dx": ((3,), f32),
                _VT + "bx": ((3,), f32), _VT + "nx": ((3,), torch.int64)}

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
        hard = bev_grid_checks(state_dict, ref.bev_grid)
        frustum = as_numpy(state_dict[_VT + "frustum"])
        checks = (TableCheck(_VT + "frustum", frustum, ref.frustum, atol=FRUSTUM_ATOL),)
        source = decide_geometry(checks, policy, context="FisheyeBEVDet-cyl checkpoint")
        geometry = ref.with_tables(frustum=frustum) if source == "checkpoint" else ref
        self.set_geometry(geometry)
        return GeometryReport(source, checks + hard)

