"""``CylindricalPETRHead``: FisheyePETR's head on features of rectified cylindrical images.

Differences from :class:`~.petr_head.FisheyePETRHead`, as in the official
``models/petr/cyl_petr_head.py``:

- no feature warp: the images were rectified before the backbone, so P3 (25 x 50) is the key grid;
- no key mask: the masks are all False, so no key is ignored and the sine encoding is a plain ramp;
- PE3D rays lie on a cylinder, q = d (sin phi_w, y_h, cos phi_w), with the official head's
  swapped unpacking of its ranges (phi from ``azimuth_range[1]`` to ``[0]``, y from
  tan(``elevation_range[1]``) to tan(``[0]``)): see
  :func:`fisheye_infer.geometry.tables.cyl_petr_directions`.

The head also holds the image rectification grid ``geom.image_grid``, so ``tables()`` lists every
table of the graph. State-dict keys are FisheyePETRHead's minus the four geometry tensors.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
import torch

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.petr import lid_depths, position_coords
from fisheye_infer.geometry.tables import CylPETRParams, cyl_image_grid, cyl_petr_directions

from .cyl_config import CylPETRConfig
from .petr_head import FisheyePETRHead

__all__ = ["CylPETRGeometry", "CylindricalPETRHead", "petr_params"]


def petr_params(cfg: CylPETRConfig) -> CylPETRParams:
    """The parameters of the head's geometry tables (what an exported file records)."""
    return CylPETRParams(feature_size=tuple(cfg.feature_size), azimuth_range=tuple(cfg.azimuth_range),
                         elevation_range=tuple(cfg.elevation_range), image_size=tuple(cfg.cylinder_size),
                         depth_num=cfg.depth_num, depth_start=cfg.depth_start,
                         position_range=tuple(cfg.position_range), num_feats=cfg.embed_dims // 2,
                         temperature=cfg.pe_temperature)


@dataclass(frozen=True)
class CylPETRGeometry:
    """image_grid (Hc, Wc, 2) float32 GridSample grid of the raw fisheye image; cam2lidar (N, 4, 4)."""

    image_grid: np.ndarray
    cam2lidar: np.ndarray
    source: str = "rig"

    @classmethod
    def from_rig(cls, rig: Any, cfg: CylPETRConfig) -> "CylPETRGeometry":
        """The rig's shared intrinsic model (one grid for every camera) and its extrinsics in rig order."""
        return cls(image_grid=cyl_image_grid(rig, petr_params(cfg)), cam2lidar=np.asarray(rig.cam2lidar(), np.float64))

    def check(self, cfg: CylPETRConfig) -> None:
        """Raise ``ConfigError`` naming the table whose shape does not fit ``cfg``."""
        expected = {"image_grid": (*cfg.cylinder_size, 2), "cam2lidar": (cfg.num_cameras, 4, 4)}
        for name, shape in expected.items():
            value = getattr(self, name)
            if tuple(np.shape(value)) != tuple(shape):
                raise ConfigError(f"geometry {name}: expected shape {tuple(shape)}, got {tuple(np.shape(value))}")
            if not np.all(np.isfinite(value)):
                raise ConfigError(f"geometry {name}: contains NaN or infinite values")


class CylindricalPETRHead(FisheyePETRHead):
    """The official ``CylindricalPETRHead`` at test time; module names and order are FisheyePETRHead's."""

    def __init__(self, cfg: CylPETRConfig, geometry: CylPETRGeometry) -> None:
        super().__init__(cfg, geometry)  # type: ignore[arg-type]
        del self.sphere_grid_2d  # no feature warp; unvalid_area stays zero: nothing is masked

    def set_geometry(self, geometry: CylPETRGeometry) -> None:  # type: ignore[override]
        """Install the rectification grid and extrinsics, and recompute the cached embeddings."""
        geometry.check(self.cfg)  # type: ignore[arg-type]
        current = getattr(self, "geometry", None)
        if isinstance(current, CylPETRGeometry) and np.array_equal(current.image_grid, geometry.image_grid) \
                and np.array_equal(current.cam2lidar, geometry.cam2lidar):
            self.geometry = geometry  # type: ignore[assignment]
            return
        self.geometry = geometry  # type: ignore[assignment]
        device = self.code_weights.device
        grid = torch.from_numpy(np.ascontiguousarray(geometry.image_grid, dtype=np.float32))[None]
        self.register_buffer("image_grid", grid.to(device), persistent=False)  # 1 x Hc x Wc x 2
        coords = self._coords(geometry.cam2lidar)
        self.coords3d.copy_(torch.from_numpy(coords).to(device))
        self.refresh_embeddings()

    def _coords(self, cam2lidar: np.ndarray) -> np.ndarray:
        """(N, 3 * depth_num, H, W) position-encoder inputs on the swapped cylinder rays."""
        params = self.params()
        depths = lid_depths(params.depth_num, params.depth_start, params.position_range[3])
        return position_coords(np.asarray(cam2lidar, dtype=np.float64).reshape(-1, 4, 4), params.feature_size,
                               depths=depths, position_range=params.position_range,
                               directions=cyl_petr_directions(params))

    def params(self) -> CylPETRParams:  # type: ignore[override]
        """The parameters of this head's geometry tables."""
        return petr_params(self.cfg)  # type: ignore[arg-type]

    def tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables an exported graph holds as named initializers."""
        return {"geom.image_grid": self.image_grid, "geom.petr.key_pos": self.key_pos,
                "geom.petr.key_mask": self.key_mask_flat}

    def warp(self, p3: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """No feature warp: B x N x C x H x W features of the rectified images are the keys."""
        fh, fw = self.cfg.feature_size
        if tuple(p3.shape[-2:]) != (fh, fw):
            raise ConfigError(f"image features are {tuple(p3.shape[-2:])}, the keys need ({fh}, {fw}): "
                              "the rectified images do not have the configured cylinder size")
        return p3
