"""BEVDet on perspective views rectified from four fisheye cameras (``configs/fisheye_to_pinhole_bevdet.py``).

    model = create_model("fisheye-bevdet-persp")               # the shipped Fisheye3DOD rig
    out = model(images_uint8)                                  # B x 4 x 800 x 800 x 3 raw fisheye BGR

The official test pipeline rectifies each fisheye image into two 400x400 perspective views of 110
degrees, turned -55 and +55 degrees about the camera's y axis, with cv2.remap
(``MultiViewFisheyePerspectiveProjection``), and its ``ImageAug3D`` then casts the float views to
uint8 (a truncation). Here both are the first ops of the graph (``geom.rectify.*``, cv2.remap's
exact taps, then Floor), so the exported file takes the raw fisheye images. The eight views go
through ResNet-18 + FPN (P3 25 x 25), the standard ``LSSTransform`` with each view's ideal pinhole
K and pose (fisheye cam2lidar @ R_y(yaw)), SECOND + SECONDFPN and TransFusion.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.pinhole_lss import PinholeLSSGeometry

from .cylindrical import check_rig_image_size
from .fisheye_bevdet import SIGNATURE_KEYS
from .front_end import perspective_views
from .frustum_bevdet import FrustumBEVDet, checkpoint_filter_fn, has_image_plane_frustum
from .pinhole_bevdet import FRUSTUM_ATOL
from .pinhole_config import PerspBEVDetConfig, PinholeViewTransformConfig
from .registry import register_model
from .transfusion import INT8_FLOAT, SCORE_SEMANTICS
from .view_transform import RectifiedLSS

__all__ = ["FisheyeBEVDetPersp"]


@register_model(
    "fisheye-bevdet-persp",
    manifest="fisheye_bevdet_persp_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=SIGNATURE_KEYS,
    absent_keys=("view_transform.sphere_grid_2d",),
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
    predicate=has_image_plane_frustum,
)
class FisheyeBEVDetPersp(FrustumBEVDet):
    """Perspective-view BEV detector: cv2.remap rectification (two views per fisheye), ResNet-18 + FPN,
    standard LSS, SECOND, TransFusion."""

    config_cls = PerspBEVDetConfig
    config: PerspBEVDetConfig
    FRUSTUM_ATOL = FRUSTUM_ATOL

    def _check_rig(self, rig: Rig) -> None:
        check_rig_image_size(rig, self.config.image.height, self.config.image.width, "image.height/width")

    def _build_view_transform(self, cfg: PinholeViewTransformConfig, geometry: Any) -> RectifiedLSS:  # type: ignore[override]
        return RectifiedLSS(cfg, geometry)

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw fisheye (BGR) -> float32 (B*N*Y) x 3 x h x w normalised views, Y per camera.

        Rectification runs on raw pixel values, the uint8 truncation (``perspective.truncate``) and
        normalisation after it, as in the official pipeline (`perspective_views`).
        """
        g, p = self.view_transform.geometry, self.config.perspective
        assert isinstance(g, PinholeLSSGeometry) and g.image_grid is not None  # perspective views have a remap grid
        x = perspective_views(
            images,
            tables or self.geometry_tables(),
            g.image_grid,
            g.params.source_size,
            len(p.yaws),
            p.size,
            p.truncate,
        )
        x = (x - self.mean.reshape(1, 1, 1, 3, 1, 1)) / self.std.reshape(1, 1, 1, 3, 1, 1)
        return x.reshape(-1, 3, *p.size)

    def forward_dynamic(
        self, images: torch.Tensor, cam2lidar: torch.Tensor | np.ndarray, camera_valid: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        raise ConfigError(
            "fisheye-bevdet-persp: per-frame extrinsics are not supported; build the model for the frame's rig instead"
        )
