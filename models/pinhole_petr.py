"""PETR on six pinhole cameras (``configs/nusc_petr.py``) in plain PyTorch.

    model = create_model("pinhole-petr", rig=Rig.load("rig-pinhole6/cameras.json"))
    out = model(images_uint8)                                  # B x 6 x 720 x 1280 x 3 raw BGR

The official test pipeline resizes each 1280x720 image to 800x450 with PIL's bicubic filter and
crops rows 50..449 (``ResizeCropFlipImage``), updating ``cam2img`` by the same transform; here the
resize and crop are the first ops of the graph (``geom.resize.*``, [`front_end`][fisheye_infer.models.front_end]). Then
ResNet-18 + FPN (P3 25 x 50) and the standard ``PETRHead``: keys at the views' pixels, lifted
through ``inv(lidar2img)`` ([`pinhole_petr`][fisheye_infer.geometry.pinhole_petr]), the same decoder and
NMS-free decoding as FisheyePETR.

The released ``nusc_petr.py`` does not pack ``img_shape`` into the metadata and crashes in the
official test path; with it added (the only change), the key mask is all False, as here. The
exporter reads only what it needs from the released file, so it takes it as released.
"""

from __future__ import annotations

from typing import Any

import torch

from .fisheye_petr import _HEAD, SIGNATURE_KEYS, checkpoint_filter_fn
from .front_end import resized_views
from .normalise import normalise_frames
from .petr_config import PETRConfig
from .petr_head import INT8_FLOAT, SCORE_SEMANTICS, RectifiedPETRHead
from .pinhole_petr_config import PinholePETRConfig
from .registry import register_model
from .resampled_petr import ResampledPETR

__all__ = ["PinholePETR"]


@register_model(
    "pinhole-petr",
    manifest="pinhole_petr_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=SIGNATURE_KEYS,
    absent_keys=(_HEAD + "sphere_grid_2d",),
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
)
class PinholePETR(ResampledPETR):
    """PIL resize and crop -> normalisation -> ResNet-18 -> FPN (P3 only) -> PETRHead -> NMS-free decoding."""

    config_cls = PinholePETRConfig
    config: PinholePETRConfig

    def _build_head(self, cfg: PETRConfig, geometry: Any) -> RectifiedPETRHead:
        return RectifiedPETRHead(cfg, geometry)

    def views(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw pinhole images -> float B x N x h x w x 3 views of uint8 values: PIL's resize
        and the crop ([`front_end.resized_views`][fisheye_infer.models.front_end.resized_views])."""
        cfg = self.config
        source_hw = (cfg.image.height, cfg.image.width)
        return resized_views(images, tables or self.geometry_tables(), source_hw, cfg.head.image_size)

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 raw pinhole images (BGR) -> float (B*N) x 3 x h x w normalised views."""
        views = self.views(images, tables)
        return normalise_frames(views, self.pixel_mean, self.pixel_std, self.config.image.bgr_to_rgb)
