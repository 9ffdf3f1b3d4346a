"""What every detector shares: its configuration, its rig's geometry, input checks and official state.

    class FisheyeBEVDet(FisheyeDetector):
        config_cls = BEVDetConfig
        def __init__(self, config=None, rig=None, geometry=None):
            super().__init__(config, rig, geometry)     # self.config, self.camera_names, self.rig_geometry
            ...                                         # the layers, in the official order

The geometry comes from :func:`fisheye_infer.geometry.kinds.geometry_from_rig` for the
configuration's ``geometry_params()``: the model never computes a table, it installs the
geometry object's tables as buffers. A subclass that needs more of the rig than its camera count
overrides :meth:`FisheyeDetector._check_rig`.
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from fisheye_infer.errors import ConfigError, FrameError
from fisheye_infer.geometry.kinds import Geometry, GeometryParams, geometry_from_rig
from fisheye_infer.rig import Rig

from .checkpoint import GeometryReport, KeySpec
from .config import ModelConfig

__all__ = ["FisheyeDetector"]


class FisheyeDetector(nn.Module):
    """Base of the plain-PyTorch detectors: uint8 BGR images (B, N, H, W, 3) in, fixed-size boxes out."""

    config_cls: ClassVar[type[ModelConfig]]

    def __init__(self, config: Any = None, rig: Rig | None = None, geometry: Geometry | None = None) -> None:
        super().__init__()
        self.config = cfg = config if config is not None else self.config_cls()
        if geometry is None:
            if rig is None:
                from fisheye_infer.rig import default_rig

                rig = default_rig()
            if len(rig) != cfg.num_cameras:
                raise ConfigError(f"the rig has {len(rig)} cameras ({', '.join(rig.names)}); the configuration "
                                  f"expects {cfg.num_cameras} ({', '.join(cfg.image.camera_names)})")
            self._check_rig(rig)
            geometry = geometry_from_rig(rig, cfg.geometry_params())
        self.camera_names = tuple(rig.names) if rig is not None else tuple(cfg.image.camera_names)
        self.rig_geometry = geometry  # recomputed tables; the reference for checkpoint comparison

    def _check_rig(self, rig: Rig) -> None:
        """Refuse a rig the configuration cannot use (the camera count is checked already)."""

    def _check_images(self, images: torch.Tensor, camera_valid: torch.Tensor | None) -> None:
        n = len(self.camera_names)
        h, w = self.config.image.height, self.config.image.width
        if images.dim() != 5 or tuple(images.shape[1:]) != (n, h, w, 3):
            raise FrameError(f"images: expected (B, {n}, {h}, {w}, 3) BGR, got {tuple(images.shape)}")
        if camera_valid is not None and tuple(camera_valid.shape) != (images.shape[0], n):
            raise FrameError(f"camera_valid: expected ({images.shape[0]}, {n}), got {tuple(camera_valid.shape)}")

    # -- geometry -----------------------------------------------------------------------

    def geometry_tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables the exported graph holds as named initializers (the installed buffers)."""
        raise NotImplementedError

    def geometry_params(self) -> GeometryParams:
        """The parameters that define the geometry tables (what a re-baked file recomputes them from)."""
        return self.config.geometry_params()  # type: ignore[no-any-return]

    def table_weights(self) -> dict[str, np.ndarray] | None:
        """The weights the geometry tables depend on (FisheyePETR's key embedding), or ``None``."""
        return None

    def set_geometry(self, geometry: Any) -> None:
        """Install other geometry tables (same configuration)."""
        raise NotImplementedError

    # -- official checkpoint ----------------------------------------------------------------

    def official_keys(self) -> dict[str, KeySpec]:
        """Every key of the official checkpoint in official order, with shape and dtype."""
        raise NotImplementedError

    def official_geometry_state(self) -> dict[str, torch.Tensor]:
        """The geometry tables in official form, as an official checkpoint stores them."""
        raise NotImplementedError

    def official_state_dict(self) -> dict[str, torch.Tensor]:
        """This model's weights and geometry under the official names, in official order."""
        weights = self.state_dict()
        geometry = self.official_geometry_state()
        return {k: (geometry[k] if k in geometry else weights[k]).detach().clone() for k in self.official_keys()}

    def apply_checkpoint_geometry(self, state_dict: Any, policy: str) -> GeometryReport:
        """Compare the stored tables with the rig's and install the ones ``policy`` selects."""
        raise NotImplementedError
