"""BEVDet on six pinhole cameras (``configs/nusc_bevdet.py``) in plain PyTorch.

    model = create_model("pinhole-bevdet", rig=Rig.load("rig-pinhole6/cameras.json"))
    out = model(images_uint8)                                  # B x 6 x 720 x 1280 x 3 raw BGR

The official test pipeline resizes each 1280x720 image to 800x450 with PIL's bicubic filter and
crops rows 50..449 (``ImageAug3D``); here both are the first ops of the graph (``geom.resize.*``,
PIL's fixed-point arithmetic reproduced exactly, `resize`), so the exported file takes the
raw camera images. Then ResNet-18 + FPN (P3 25 x 50), the standard ``LSSTransform`` (depthnet on P3,
the image-plane frustum undone through the crop, the resize and ``inv(K)``, the bucketed mean
pool), SECOND + SECONDFPN and TransFusion, with the official module names.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from fisheye_infer.errors import ConfigError

from .fisheye_bevdet import SIGNATURE_KEYS
from .front_end import resized_views
from .frustum_bevdet import FrustumBEVDet, checkpoint_filter_fn, has_image_plane_frustum
from .normalise import normalise_frames
from .pinhole_config import PinholeBEVDetConfig, PinholeViewTransformConfig
from .registry import register_model
from .transfusion import INT8_FLOAT, SCORE_SEMANTICS
from .view_transform import RectifiedLSS

__all__ = ["PinholeBEVDet"]

#: The stored frustum's pixel coordinates come from float32 ``linspace`` (up to one ulp of 799, 6e-5).
FRUSTUM_ATOL = 1e-3


@register_model(
    "pinhole-bevdet",
    manifest="pinhole_bevdet_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=SIGNATURE_KEYS,
    absent_keys=("view_transform.sphere_grid_2d",),
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
    predicate=has_image_plane_frustum,
)
class PinholeBEVDet(FrustumBEVDet):
    """Pinhole BEV detector: PIL resize and crop, ResNet-18 + FPN, standard LSS, SECOND, TransFusion."""

    config_cls = PinholeBEVDetConfig
    config: PinholeBEVDetConfig
    FRUSTUM_ATOL = FRUSTUM_ATOL

    def _build_view_transform(self, cfg: PinholeViewTransformConfig, geometry: Any) -> RectifiedLSS:  # type: ignore[override]
        return RectifiedLSS(cfg, geometry)

    def views(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw pinhole images -> float B x N x h x w x 3 views of uint8 values: PIL's resize
        and the crop ([`front_end.resized_views`][fisheye_infer.models.front_end.resized_views]), on the raw pixel
        values (the channel order does not matter to them)."""
        cfg = self.config
        source_hw = (cfg.image.height, cfg.image.width)
        return resized_views(images, tables or self.geometry_tables(), source_hw, cfg.view_transform.image_size)

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw pinhole images (BGR) -> float32 (B*N) x 3 x h x w normalised views."""
        return normalise_frames(self.views(images, tables), self.mean, self.std)

    def forward_dynamic(
        self, images: torch.Tensor, cam2lidar: torch.Tensor | np.ndarray, camera_valid: torch.Tensor | None = None
    ) -> dict[str, torch.Tensor]:
        raise ConfigError(
            "pinhole-bevdet: per-frame extrinsics are not supported; build the model for the frame's rig instead"
        )
