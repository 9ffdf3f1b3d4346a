"""What the PETR baselines without a feature warp share: an image front end, views, and no stored geometry.

The cylinder-rectified, perspective-rectified and pinhole PETR configs resample the raw camera
images before the backbone (the front end: each config's ``normalise``), use the stride-16
features of the resulting views as keys (`RectifiedPETRHead`), and their
checkpoints hold no geometry tensor: every table comes from the rig. A front end may make several
views of one camera (two perspective views per fisheye): a missing camera masks all of its views
([`view_valid`][fisheye_infer.models.base.FisheyeDetector.view_valid]).
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
    """FisheyePETR with an image front end and no feature warp; subclasses define ``normalise`` (the front
    end) and the head."""

    def normalize(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Deprecated: `normalise`, whose views come flat, (B*V) x 3 x h x w; this keeps the old
        B x V x 3 x h x w."""
        self._deprecated("normalize", "normalise")
        x = self.normalise(images, tables)
        return x.reshape(images.shape[0], -1, *x.shape[1:])

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        """None: these heads store no geometry tensor."""
        return {}

    def _official_tables(self, geometry: Any) -> dict[str, np.ndarray]:
        return {}

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Nothing to compare: the tables always come from the rig, whatever the (valid) policy."""
        if policy not in GEOMETRY_POLICIES:
            raise CheckpointError(
                f"geometry={policy!r} is not a geometry policy (use one of {', '.join(GEOMETRY_POLICIES)})"
            )
        self.set_geometry(self.rig_geometry)
        return GeometryReport("rig", ())
