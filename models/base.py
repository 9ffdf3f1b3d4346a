"""What every detector shares: its configuration, its rig's geometry, input checks and official state.

    class FisheyeBEVDet(FisheyeDetector):
        config_cls = BEVDetConfig
        def __init__(self, config=None, rig=None, geometry=None):
            super().__init__(config, rig, geometry)     # self.config, self.camera_names, self.rig_geometry
            ...                                         # the layers, in the official order

The geometry comes from [`geometry_from_rig`][fisheye_infer.geometry.kinds.geometry_from_rig] for the
configuration's ``geometry_params()``: the model never computes a table, it installs the
geometry object's tables as buffers. A subclass that needs more of the rig than its camera count
overrides `FisheyeDetector._check_rig`.

Both families run the same stages, which this class names so that callers (export, calibration,
tests) need not know the family:

    normalise(images, tables)                   uint8 camera images -> float backbone input, V views per frame
    image_features(images, tables)              -> (B, V, C, h, w) stride-16 features (ResNet + FPN level 0)
    scene_features(feats, valid, tables, ...)   -> what the head reads: BEV features after the view transform
                                                   (BEVDet) or object queries decoded against the keys'
                                                   3D position embedding (PETR)
    head_outputs(scene)                         -> decoded boxes, scores, labels, valid, ranking outputs
    predict(images, camera_valid, tables)       all four, without input checks; ``forward`` checks first
"""

from __future__ import annotations

import warnings
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError, FrameError
from fisheye_infer.geometry.kinds import Geometry, GeometryParams, geometry_from_rig

from .backbone import FPN, ResNet
from .checkpoint import GeometryReport, KeySpec
from .config import ModelConfig

__all__ = ["FisheyeDetector"]


class FisheyeDetector(nn.Module):
    """Base of the plain-PyTorch detectors: uint8 BGR images (B, N, H, W, 3) in, fixed-size boxes out."""

    config_cls: ClassVar[type[ModelConfig]]
    config: ModelConfig  # each family narrows it to its configuration class
    # Built by each family under the official checkpoint names; ``image_features`` runs them.
    img_backbone: ResNet
    img_neck: FPN

    def __init__(self, config: Any = None, rig: Rig | None = None, geometry: Geometry | None = None) -> None:
        super().__init__()
        self.config = cfg = config if config is not None else self.config_cls()
        if geometry is None:
            if rig is None:
                from fisheye_infer.cameras.rig import default_rig

                rig = default_rig()
            if len(rig) != cfg.num_cameras:
                raise ConfigError(
                    f"the rig has {len(rig)} cameras ({', '.join(rig.names)}); the configuration "
                    f"expects {cfg.num_cameras} ({', '.join(cfg.image.camera_names)})"
                )
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

    def _deprecated(self, old: str, new: str) -> None:
        """Warn that the stage method ``old`` is now ``new``; the old name works for one more release."""
        warnings.warn(
            f"{type(self).__name__}.{old} is deprecated and will be removed in the next release; use {new}",
            DeprecationWarning,
            stacklevel=3,
        )

    # -- stages ---------------------------------------------------------------------------

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 (B, N, H, W, 3) BGR camera images -> float32 (B*V, 3, h, w) backbone input, V views per frame.

        A fisheye model normalises the frames as they are (V = N, ``tables`` unused: it warps
        features, not images). A model with an image front end resamples the raw pixels first (onto
        a cylinder, into perspective views, or resized and cropped) with the front end's tables
        from ``tables`` (default: the installed ones), and may make several views of one camera.
        """
        raise NotImplementedError

    def image_features(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 (B, N, H, W, 3) images -> (B, V, C, h, w) stride-16 features: FPN level 0, the only one
        either family reads."""
        b = images.shape[0]
        p3 = self.img_neck(self.img_backbone(self.normalise(images, tables)))[0]
        return p3.reshape(b, p3.shape[0] // b, *p3.shape[1:])

    def scene_features(
        self,
        feats: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
        cam2lidar: Any = None,
    ) -> torch.Tensor:
        """Image features (B, V, C, h, w) -> what the head reads (BEVDet: (B, C, X, Y) BEV features from the view
        transform; PETR: (B, Q, C) object queries decoded against the keys and their 3D position embedding).

        ``camera_valid`` (B, V) masks missing views (`view_valid` expands a per-camera mask);
        ``tables`` replaces the installed geometry tables (the exporter passes them as graph
        inputs); ``cam2lidar`` (B, N, 4, 4) replaces the baked extrinsics per frame (a reference
        path for parity on dataset frames, not exportable).
        """
        raise NotImplementedError

    def head_outputs(self, scene: torch.Tensor) -> dict[str, torch.Tensor]:
        """Scene features -> the decoded ``OUTPUTS`` and ``RANKING_OUTPUTS`` (and whatever else the head computes)."""
        raise NotImplementedError

    def predict(
        self,
        images: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
        cam2lidar: Any = None,
    ) -> dict[str, torch.Tensor]:
        """Every stage in order, without the input checks of ``forward``; every head output.

        Image size is not checked here: the networks are fully convolutional up to the geometry
        tables, which synthetic-checkpoint calibration uses to run on smaller frames.
        """
        tables = tables or self.geometry_tables()
        feats = self.image_features(images, tables)
        return self.head_outputs(
            self.scene_features(feats, self.view_valid(camera_valid, feats.shape[1]), tables, cam2lidar)
        )

    @staticmethod
    def view_valid(camera_valid: torch.Tensor | None, views: int) -> torch.Tensor | None:
        """Per-camera (B, N) validity -> per-view (B, V): a front end may make several views of one camera,
        and a missing camera masks all of them."""
        if camera_valid is None or camera_valid.shape[1] == views:
            return camera_valid
        return camera_valid.repeat_interleave(views // camera_valid.shape[1], dim=1)

    # -- geometry -----------------------------------------------------------------------

    def geometry_tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables the exported graph holds as named initializers (the installed buffers)."""
        raise NotImplementedError

    def geometry_params(self) -> GeometryParams:
        """The parameters that define the geometry tables (what a re-baked file recomputes them from)."""
        return self.config.geometry_params()

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
