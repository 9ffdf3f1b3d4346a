"""fisheye-petr-cyl's geometry: the image rectification grid and the keys' embedding on cylinder rays.

Differences from [`petr`][fisheye_infer.geometry.petr], as in the official ``CylindricalPETRHead``: no feature warp (the
images are rectified before the backbone, ``geom.rectify.*``), no key mask (nothing is masked,
so the sine encoding is a plain ramp), and the key rays lie on a cylinder,
q = d (sin phi_w, y_h, cos phi_w), with the official head's swapped unpacking of its ranges
(`CylPETRParams.directions`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Literal

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.cyl_lss import cyl_image_grid
from fisheye_infer.geometry.grids import cylindrical_directions
from fisheye_infer.geometry.petr import PETRParams, check_tables, key_coords, key_position_embedding
from fisheye_infer.geometry.tables import RECTIFY, CylParams, key_tables, sampling_tables

__all__ = ["CylPETRParams", "CylPETRGeometry", "cyl_petr_directions"]


class CylPETRParams(PETRParams, CylParams):
    """fisheye-petr-cyl: image rectification, PETR keys on the stride-16 features, no key mask.

    PETR's parameters and the cylinder's; the key embedding's rays unpack the ranges swapped, as
    the official head does (see `cyl_petr_directions`).
    """

    kind: Literal["cyl_petr"] = "cyl_petr"  # type: ignore[assignment]

    def directions(self) -> np.ndarray:
        """(H, W, 3) rays of the keys (see `cyl_petr_directions`)."""
        return cyl_petr_directions(self)


def cyl_petr_directions(params: CylPETRParams) -> np.ndarray:
    """(H, W, 3) rays of the cylindrical PETR keys, with the official head's swapped unpacking.

    The official ``CylindricalPETRHead`` reads ``h_max, h_min = horizontal_range`` and
    ``v_max, v_min = vertical_range`` and then linspaces from "min" to "max", so its azimuth runs
    from ``azimuth_range[1]`` to ``azimuth_range[0]`` and its height from
    tan(``elevation_range[1]``) to tan(``elevation_range[0]``): both axes reversed with respect to
    the rectified image (a half turn about the optical axis). The checkpoint was trained with it.
    """
    (a0, a1), (e0, e1) = params.azimuth_range, params.elevation_range
    return cylindrical_directions(params.feature_size, (a1, a0), (math.tan(e1), math.tan(e0)))


@dataclass(frozen=True)
class CylPETRGeometry:
    """image_grid (N, Hc, Wc, 2) float32 GridSample grids of each camera's raw fisheye image; cam2lidar (N, 4, 4)."""

    params: CylPETRParams
    image_grid: np.ndarray
    cam2lidar: np.ndarray
    source: str = "rig"

    @classmethod
    def from_rig(cls, rig: Rig, params: CylPETRParams) -> CylPETRGeometry:
        """Each camera's lens model (its rectification grid) and extrinsics, in rig order."""
        return cls(
            params=params, image_grid=cyl_image_grid(rig, params), cam2lidar=np.asarray(rig.cam2lidar(), np.float64)
        )

    def check(self, num_cameras: int) -> None:
        """Raise ``ConfigError`` naming the table whose shape does not fit the parameters and camera count."""
        check_tables(
            {"image_grid": (num_cameras, *self.params.image_size, 2), "cam2lidar": (num_cameras, 4, 4)},
            {"image_grid": self.image_grid, "cam2lidar": self.cam2lidar},
        )

    @property
    def unvalid_area(self) -> np.ndarray:
        """(H, W) float32 zeros: the official head masks no key."""
        return np.zeros(self.params.feature_size, np.float32)

    def key_mask(self) -> np.ndarray:
        """(N, H, W) bool, all False."""
        return np.zeros((len(self.cam2lidar), *self.params.feature_size), bool)

    def coords(self, cam2lidar: np.ndarray | None = None) -> np.ndarray:
        """(N, 3 * depth_num, H, W) float32 position-encoder inputs on the swapped cylinder rays."""
        return key_coords(self.cam2lidar if cam2lidar is None else cam2lidar, self.params)

    def key_pos(self, weights: dict[str, np.ndarray], coords: np.ndarray | None = None) -> np.ndarray:
        """(1, N*H*W, C) float32 key embedding with ``weights``."""
        return key_position_embedding(
            self.coords() if coords is None else coords, self.unvalid_area, weights, self.params
        )

    def tables(self, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Every ``geom.*`` table of the graph; the key embedding needs the position-encoder weights."""
        if weights is None:
            raise ConfigError("weights: cylindrical PETR tables need the position_encoder and adapt_pos3d weights")
        return {**self.sampling_tables(), **key_tables(self.key_pos(weights), self.key_mask())}

    def sampling_tables(self) -> dict[str, np.ndarray]:
        """The image rectification's taps (``geom.rectify.*``) on the ``source_size`` raw images."""
        return sampling_tables(RECTIFY, self.image_grid, self.params.source_size)
