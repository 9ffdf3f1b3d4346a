"""PETR on perspective views rectified from four fisheye cameras (``configs/fisheye_to_pinhole_petr.py``).

    model = create_model("fisheye-petr-persp")                 # the shipped Fisheye3DOD rig
    out = model(images_uint8)                                  # B x 4 x 800 x 800 x 3 raw fisheye BGR

The official test pipeline rectifies each fisheye image into two 400x400 perspective views of 110
degrees, turned -55 and +55 degrees about the camera's y axis, with cv2.remap
(``MultiViewFisheyePerspectiveProjection``); unlike BEVDet's, its pipeline normalises the float
views without a uint8 cast. Here the rectification is the first op of the graph
(``geom.rectify.*``, `front_end`). The eight views go through ResNet-18 + FPN (P3 25 x 25)
and the standard ``PETRHead`` with each view's ``lidar2img`` (ideal pinhole K, pose fisheye
cam2lidar @ R_y(yaw)).

The released ``fisheye_to_pinhole_petr.py`` crashes in the official test path (one ``img_shape``
tuple for all views where the head reads one per view); with one per view (the only change) the
key mask is all False, as here. The exporter takes the file as released.
"""

from __future__ import annotations

from typing import Any

import torch

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.geometry.pinhole_petr import PinholePETRGeometry

from .cylindrical import check_rig_image_size
from .fisheye_petr import _HEAD, SIGNATURE_KEYS, checkpoint_filter_fn
from .front_end import perspective_views
from .petr_config import PETRConfig
from .petr_head import INT8_FLOAT, SCORE_SEMANTICS, RectifiedPETRHead
from .pinhole_petr_config import PerspPETRConfig
from .registry import register_model
from .resampled_petr import ResampledPETR

__all__ = ["FisheyePETRPersp"]


@register_model(
    "fisheye-petr-persp",
    manifest="fisheye_petr_persp_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=SIGNATURE_KEYS,
    absent_keys=(_HEAD + "sphere_grid_2d",),
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
)
class FisheyePETRPersp(ResampledPETR):
    """cv2.remap rectification (two views per fisheye) -> normalisation -> ResNet-18 -> FPN (P3 only) ->
    PETRHead -> NMS-free decoding."""

    config_cls = PerspPETRConfig
    config: PerspPETRConfig

    def _check_rig(self, rig: Rig) -> None:
        check_rig_image_size(rig, self.config.image.height, self.config.image.width, "image.height/width")

    def _build_head(self, cfg: PETRConfig, geometry: Any) -> RectifiedPETRHead:
        return RectifiedPETRHead(cfg, geometry)

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw fisheye (BGR) -> float (B*N*Y) x 3 x h x w normalised views, camera by camera."""
        g, p = self.pts_bbox_head.geometry, self.config.perspective
        assert isinstance(g, PinholePETRGeometry)  # what RectifiedPETRHead installs for perspective views
        x = perspective_views(
            images,
            tables or self.geometry_tables(),
            g.image_grid,
            g.params.source_size,
            len(p.yaws),
            p.size,
            p.truncate,
        )
        if self.config.image.bgr_to_rgb:
            x = x[:, :, :, [2, 1, 0]]
        x = (x - self.pixel_mean.reshape(1, 1, 1, 3, 1, 1)) / self.pixel_std.reshape(1, 1, 1, 3, 1, 1)
        return x.reshape(-1, 3, *p.size)
