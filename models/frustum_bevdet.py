"""What the BEVDet baselines without a feature warp share: an image front end, views, and a stored frustum.

The cylinder-rectified, perspective-rectified and pinhole BEVDet configs all resample the raw
camera images before the backbone (the front end: each config's ``normalise``), lift the
stride-16 features of the resulting views with no warp (`RectifiedLSS`)
and store the same geometry keys in their checkpoints: ``view_transform.frustum``, ``dx``, ``bx``,
``nx``. A front end may make several views of one camera (two perspective views per fisheye):
the features are grouped by view, and a missing camera masks all of its views
([`view_valid`][fisheye_infer.models.base.FisheyeDetector.view_valid]).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import torch

from fisheye_infer.geometry.cyl_lss import CylLSSGeometry
from fisheye_infer.geometry.pinhole_lss import PinholeLSSGeometry

from .checkpoint import GeometryReport, KeySpec, TableCheck, as_numpy, decide_geometry
from .fisheye_bevdet import FisheyeBEVDet, bev_grid_checks

__all__ = [
    "FrustumBEVDet",
    "GEOMETRY_KEYS",
    "checkpoint_filter_fn",
    "has_image_plane_frustum",
    "has_camera_frame_frustum",
]

_VT = "view_transform."
#: Official checkpoint keys holding geometry tables (not weights of this model), in official order.
GEOMETRY_KEYS = tuple(_VT + k for k in ("frustum", "dx", "bx", "nx"))


def checkpoint_filter_fn(state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Official key names -> this model's state dict: identity with the geometry keys removed."""
    return {k: v for k, v in state_dict.items() if k not in GEOMETRY_KEYS}


def has_image_plane_frustum(state_dict: Mapping[str, torch.Tensor]) -> bool:
    """Whether the stored frustum is ``LSSTransform``'s (x, y, depth) image-plane grid, as opposed to the
    camera-frame points of the cylindrical transform: the keys of the two are the same."""
    f = as_numpy(state_dict[_VT + "frustum"]) if _VT + "frustum" in state_dict else None
    if f is None or f.ndim != 4 or f.shape[-1] != 3:
        return False
    return bool(
        np.all(f[..., 2] == f[:, :1, :1, 2])
        and np.all(f[..., 0] == f[:1, :1, :, 0])
        and np.all(f[..., 1] == f[:1, :, :1, 1])
    )


def has_camera_frame_frustum(state_dict: Mapping[str, torch.Tensor]) -> bool:
    """The complement of `has_image_plane_frustum` for a checkpoint that stores a frustum."""
    return _VT + "frustum" in state_dict and not has_image_plane_frustum(state_dict)


class FrustumBEVDet(FisheyeBEVDet):
    """BEVDet with an image front end and no feature warp; subclasses define ``normalise`` (the front
    end) and the view transform.

    ``FRUSTUM_ATOL`` is how far the checkpoint's stored frustum may lie from the recomputed one and
    still describe the same geometry (float32 rounding of the official constructor).
    """

    FRUSTUM_ATOL: ClassVar[float]

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        vt = self.config.view_transform
        h, w = vt.feature_size
        f32 = torch.float32
        return {
            _VT + "frustum": ((vt.num_depth_bins, h, w, 3), f32),
            _VT + "dx": ((3,), f32),
            _VT + "bx": ((3,), f32),
            _VT + "nx": ((3,), torch.int64),
        }

    def official_geometry_state(self) -> dict[str, torch.Tensor]:
        """The geometry tables in official form, as an official checkpoint stores them."""
        g = self.view_transform.geometry
        bev = g.bev_grid
        t = torch.from_numpy
        return {
            _VT + "frustum": t(g.frustum.copy()),
            _VT + "dx": t(bev.dx.copy()),
            _VT + "bx": t(bev.bx.copy()),
            _VT + "nx": torch.tensor(bev.nx, dtype=torch.int64),
        }

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Compare the stored frustum and BEV grid with the rig's and install what ``policy`` selects."""
        ref = self.rig_geometry
        assert isinstance(ref, (CylLSSGeometry, PinholeLSSGeometry))  # what the front-end configurations make
        hard = bev_grid_checks(state_dict, ref.bev_grid)
        frustum = as_numpy(state_dict[_VT + "frustum"])
        checks = (TableCheck(_VT + "frustum", frustum, ref.frustum, atol=self.FRUSTUM_ATOL),)
        source = decide_geometry(checks, policy, context=f"{type(self).__name__} checkpoint")
        geometry = ref.with_tables(frustum=frustum) if source == "checkpoint" else ref
        self.set_geometry(geometry)
        return GeometryReport(source, checks + hard)

    def set_geometry(self, geometry: Any) -> None:
        """Install other geometry tables (same configuration), keeping the device of the weights."""
        device = self.view_transform.depthnet.weight.device
        self.view_transform.set_geometry(geometry)
        self.view_transform.to(device)
