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
(``frustum``, ``dx``, ``bx``, ``nx``), which are checked against the rig and installed separately
([`frustum_bevdet`][fisheye_infer.models.frustum_bevdet]).
"""

from __future__ import annotations

from typing import Any

import torch

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry.cyl_lss import CylLSSGeometry
from fisheye_infer.geometry.tables import RECTIFY

from .cyl_config import BEVDetCylConfig, CylViewTransformConfig
from .cylindrical import check_rig_image_size, rectify
from .fisheye_bevdet import SIGNATURE_KEYS
from .frustum_bevdet import GEOMETRY_KEYS, FrustumBEVDet, checkpoint_filter_fn, has_camera_frame_frustum
from .registry import register_model
from .resample import taps_for
from .transfusion import INT8_FLOAT, SCORE_SEMANTICS
from .view_transform import CylindricalLSS

__all__ = ["FisheyeBEVDetCyl", "checkpoint_filter_fn", "GEOMETRY_KEYS", "FRUSTUM_ATOL"]

# The official frustum is float32 torch arithmetic on float32 linspace angles. Taken literally the
# released ranges span +-110 rad, where one float32 ulp of the angle is 7.6e-6 rad, i.e. 0.4 mm at
# 48.5 m; other ranges move points by metres.
FRUSTUM_ATOL = 2e-3


@register_model(
    "fisheye-bevdet-cyl",
    manifest="fisheye_bevdet_cyl_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=SIGNATURE_KEYS,
    absent_keys=("view_transform.sphere_grid_2d",),
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
    predicate=has_camera_frame_frustum,
)
class FisheyeBEVDetCyl(FrustumBEVDet):
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
    calibration file), so it always comes from the rig.
    """

    config_cls = BEVDetCylConfig
    config: BEVDetCylConfig
    FRUSTUM_ATOL = FRUSTUM_ATOL

    def _check_rig(self, rig: Rig) -> None:
        check_rig_image_size(rig, self.config.image.height, self.config.image.width, "image.height/width")

    def _build_view_transform(self, cfg: CylViewTransformConfig, geometry: Any) -> CylindricalLSS:  # type: ignore[override]
        return CylindricalLSS(cfg, geometry)

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw fisheye (BGR) -> float32 (B*N) x 3 x Hc x Wc normalised cylinder images.

        Rectification runs on raw pixel values, normalisation after it, as in the official pipeline;
        frames of another size than the configured one (synthetic-checkpoint calibration uses
        smaller ones) are rectified to the configured cylinder all the same.
        """
        g = self.view_transform.geometry
        assert isinstance(g, CylLSSGeometry)  # what CylindricalLSS installs
        index, weight = taps_for(
            tables or self.geometry_tables(),
            RECTIFY,
            g.image_grid,
            g.params.source_size,
            images.shape[2:4],
            images.device,
        )
        x = rectify(images, index, weight, g.params.image_size)  # B x N x 3 x Hc x Wc
        x = (x - self.mean.reshape(1, 1, 3, 1, 1)) / self.std.reshape(1, 1, 3, 1, 1)
        return x.flatten(0, 1)
