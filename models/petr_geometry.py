"""The calibration tables FisheyePETR consumes, gathered from a rig by the numpy geometry.

The head never computes geometry itself: it receives a ``PETRGeometry`` holding the shared
equirectangular warp grid, the lens-validity mask sampled on it (``unvalid_area``) and the
per-camera cam2lidar matrices, all produced by :mod:`fisheye_infer.geometry`.

    geom = PETRGeometry.from_rig(default_rig(), cfg)
    geom = PETRGeometry(grid=ckpt_grid, unvalid_area=ckpt_mask, cam2lidar=rig.cam2lidar())
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import invalid_mask, spherical_grid

from .petr_config import PETRConfig

__all__ = ["PETRGeometry"]


@dataclass(frozen=True)
class PETRGeometry:
    """grid (H, W, 2) float32 for grid_sample(align_corners=True); unvalid_area (H, W) float32,
    a key is masked where it is not exactly 0; cam2lidar (N, 4, 4) in the model's camera order."""

    grid: np.ndarray
    unvalid_area: np.ndarray
    cam2lidar: np.ndarray
    source: str = "rig"  # where grid and mask came from: "rig" or "checkpoint"

    @classmethod
    def from_rig(cls, rig: Any, cfg: PETRConfig) -> "PETRGeometry":
        """Grid and mask from the rig's one shared intrinsic model, extrinsics in rig order.

        The official model was trained with one intrinsic model for all cameras (one grid,
        one mask), so a rig whose cameras differ is refused by ``Rig.shared_model``.
        """
        camera = rig.shared_model()
        grid = spherical_grid(camera, cfg.feature_size, cfg.azimuth_range, cfg.elevation_range)
        return cls(grid=grid, unvalid_area=invalid_mask(camera, grid), cam2lidar=rig.cam2lidar())

    @classmethod
    def default(cls, cfg: PETRConfig) -> "PETRGeometry":
        """The shipped Fisheye3DOD rig (one 800x800 220-degree OCam model, four cameras)."""
        from fisheye_infer.rig import default_rig

        return cls.from_rig(default_rig(), cfg)

    def with_tables(self, *, grid: np.ndarray | None = None, unvalid_area: np.ndarray | None = None,
                    source: str = "checkpoint") -> "PETRGeometry":
        """Same extrinsics with the warp grid and/or mask replaced (e.g. by a checkpoint's tables)."""
        new_grid = self.grid if grid is None else np.asarray(grid, dtype=np.float32)
        new_mask = self.unvalid_area if unvalid_area is None else np.asarray(unvalid_area, dtype=np.float32)
        return replace(self, grid=new_grid, unvalid_area=new_mask.reshape(new_grid.shape[:2]), source=source)

    def check(self, cfg: PETRConfig) -> None:
        """Raise ``ConfigError`` naming the table whose shape does not fit ``cfg``."""
        fh, fw = cfg.feature_size
        expected = {"grid": (fh, fw, 2), "unvalid_area": (fh, fw), "cam2lidar": (cfg.num_cameras, 4, 4)}
        for name, shape in expected.items():
            got = tuple(np.shape(getattr(self, name)))
            if name == "unvalid_area" and got == (1, 1, fh, fw):
                continue
            if got != shape:
                raise ConfigError(f"geometry {name}: expected shape {shape}, got {got}")
            if not np.all(np.isfinite(getattr(self, name))):
                raise ConfigError(f"geometry {name}: contains NaN or infinite values")
