"""What the PETR baselines without a feature warp share: an image front end, views, and no stored geometry.

The cylinder-rectified, perspective-rectified and pinhole PETR configs resample the raw camera
images before the backbone (the front end, :meth:`ResampledPETR.normalize`), use the stride-16
features of the resulting views as keys (:class:`~.petr_head.RectifiedPETRHead`), and their
checkpoints hold no geometry tensor: every table comes from the rig. A front end may make several
views of one camera (two perspective views per fisheye): a missing camera masks all of its views.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np
import torch

from fisheye_infer.errors import CheckpointError

from .checkpoint import GEOMETRY_POLICIES, GeometryReport, KeySpec
from .fisheye_petr import FisheyePETR

__all__ = ["ResampledPETR"]


class ResampledPETR(FisheyePETR):
    """FisheyePETR with an image front end and no feature warp; subclasses define ``normalize`` and the head."""

    def normalize(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:  # type: ignore[override]
        """uint8 B x N x H x W x 3 raw camera images (BGR) -> float B x V x 3 x h x w normalised views, V per frame."""
        raise NotImplementedError

    def forward_features(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:  # type: ignore[override]
        """Raw images (any size: they are resampled to the configured views) -> P3 B x V x C x H x W."""
        x = self.normalize(images, tables)
        b, v = x.shape[:2]
        p3 = self.img_neck(self.img_backbone(x.reshape(b * v, *x.shape[2:])))[0]
        return p3.reshape(b, v, *p3.shape[1:])

    def forward(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None,
                cam2lidar: Any = None, tables: dict[str, torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
        """As :meth:`FisheyePETR.forward`; ``tables`` also supplies the front end's; each camera's views share its ``camera_valid``."""
        self._check_images(images, camera_valid)
        tables = tables or self.geometry_tables()
        p3 = self.forward_features(images, tables)
        per_camera = p3.shape[1] // images.shape[1]
        if camera_valid is not None and per_camera > 1:
            camera_valid = camera_valid.repeat_interleave(per_camera, dim=1)
        return self.pts_bbox_head(p3, camera_valid, cam2lidar, tables)

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        """None: these heads store no geometry tensor."""
        return {}

    def _official_tables(self, geometry: Any) -> dict[str, np.ndarray]:
        return {}

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Nothing to compare: the tables always come from the rig, whatever the (valid) policy."""
        if policy not in GEOMETRY_POLICIES:
            raise CheckpointError(f"geometry={policy!r} is not a geometry policy (use one of {', '.join(GEOMETRY_POLICIES)})")
        self.set_geometry(self.rig_geometry)
        return GeometryReport("rig", ())
