"""FisheyePETR on cylindrical images (``configs/fisheye_to_cyl_petr.py``) in plain PyTorch.

    model = create_model("fisheye-petr-cyl")                   # released geometry (see below)
    model, report = load_model("fisheye-petr-cyl", "cyl_petr.pth")
    out = model(images_uint8)                                  # B x 4 x 800 x 800 x 3 raw fisheye BGR

The official pipeline rectifies each raw fisheye image onto a 400 x 800 cylinder with cv2.remap
before normalisation; here that is the first op of the graph (``geom.rectify.*``), so an exported
model takes raw uint8 fisheye frames like FisheyePETR. After it: the same ResNet-18 + FPN (P3
25 x 50) and `CylindricalPETRHead`. The checkpoint holds no geometry
tensor: its keys are FisheyePETR's minus ``frustum``, ``sphere_grid_3d``, ``sphere_grid_2d`` and
``unvalid_area``, and every geometry table comes from the rig ([`resampled_petr`][fisheye_infer.models.resampled_petr]).
"""

from __future__ import annotations

from typing import Any

import torch

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry.cyl_petr import CylPETRGeometry
from fisheye_infer.geometry.tables import RECTIFY

from .cyl_config import CylPETRConfig
from .cylindrical import check_rig_image_size, rectify
from .fisheye_petr import _HEAD, SIGNATURE_KEYS, checkpoint_filter_fn
from .petr_config import PETRConfig
from .petr_head import INT8_FLOAT, SCORE_SEMANTICS, CylindricalPETRHead
from .registry import register_model
from .resample import taps_for
from .resampled_petr import ResampledPETR

__all__ = ["FisheyePETRCyl"]


@register_model(
    "fisheye-petr-cyl",
    manifest="fisheye_petr_cyl_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=SIGNATURE_KEYS,
    absent_keys=(_HEAD + "sphere_grid_2d",),
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
)
class FisheyePETRCyl(ResampledPETR):
    """Rectification -> normalisation -> ResNet-18 -> FPN (P3 only) -> CylindricalPETRHead -> NMS-free decoding.

    Degrees as radians: the released config passes ``horizontal_range=(-110, 110)`` and
    ``vertical_range=(-45, 45)`` (degrees) to the pipeline and to the head, whose code uses them as
    radians. ``CylPETRConfig.head.azimuth_range`` / ``elevation_range`` are taken as radians exactly as
    written, so the default configuration and ``CylPETRConfig.from_mmdet3d_config`` of the released
    file reproduce that geometry (azimuth over +-110 rad, 0.2753 rad per image column, heights
    +-tan(45 rad) = +-1.6197752); ``math.radians(110)`` / ``math.radians(45)`` in the config give the
    intended one. Unlike FisheyeBEVDet-cyl, the checkpoint stores no geometry that would tell the
    two apart, so the configuration decides.

    The head unpacks its ranges swapped (both position-embedding axes reversed with respect to the
    image), in either case: that is the head's code, which the checkpoint was trained with.
    Missing cameras behave as in FisheyePETR.
    """

    config_cls = CylPETRConfig
    config: CylPETRConfig

    def _check_rig(self, rig: Rig) -> None:
        check_rig_image_size(rig, self.config.image.height, self.config.image.width, "image.height/width")

    def _build_head(self, cfg: PETRConfig, geometry: Any) -> CylindricalPETRHead:
        return CylindricalPETRHead(cfg, geometry)

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw fisheye (BGR) -> float (B*N) x 3 x Hc x Wc normalised cylinder images.

        Rectification runs on raw pixel values, normalisation after it, as in the official pipeline.
        """
        g = self.pts_bbox_head.geometry
        assert isinstance(g, CylPETRGeometry)  # what CylindricalPETRHead installs
        index, weight = taps_for(
            tables or self.geometry_tables(),
            RECTIFY,
            g.image_grid,
            g.params.source_size,
            images.shape[2:4],
            images.device,
        )
        x = rectify(images, index, weight, g.params.image_size)
        if self.config.image.bgr_to_rgb:
            x = x[:, :, [2, 1, 0]]
        return ((x - self.pixel_mean) / self.pixel_std).flatten(0, 1)
