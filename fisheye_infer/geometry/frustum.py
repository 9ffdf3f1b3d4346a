"""Frustum points: where each (depth bin, feature cell) of a camera sits in 3D.

The fisheye LSS view transform lifts every cell of the angular feature grid along its ray at
each depth bin. Depth is the Euclidean range along the unit ray (not z-depth) for the
equirectangular grid, and the horizontal radius for the cylindrical one.
"""

from __future__ import annotations

import numpy as np

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import (
    DEFAULT_AZIMUTH_RANGE,
    DEFAULT_ELEVATION_RANGE,
    cylindrical_directions,
    spherical_directions,
)

__all__ = ["depth_bins", "linspace_depth_bins", "spherical_frustum", "cylindrical_frustum", "frustum_to_lidar"]


def depth_bins(dbound: tuple[float, float, float] = (0.5, 48.5, 0.5)) -> np.ndarray:
    """Depths ``arange(start, stop, step)`` (stop excluded), float32: 0.5 ... 48.0 by default."""
    start, stop, step = dbound
    count = int(np.ceil((stop - start) / step))
    return (start + step * np.arange(count, dtype=np.float64)).astype(np.float32)


def linspace_depth_bins(dbound: tuple[float, float, float] = (0.5, 48.5, 0.5)) -> np.ndarray:
    """Depths ``linspace(start, stop, int((stop - start) / step))`` (stop included), float32.

    The cylindrical LSS of the official baselines spaces its bins this way: 0.5 ... 48.5 in
    steps of 48/95 by default, one bin count with `depth_bins` but different depths.
    """
    start, stop, step = dbound
    count = int((stop - start) / step) if step > 0 else 0
    if count < 1:
        raise ConfigError(f"dbound={tuple(dbound)}: expected start < stop and 0 < step <= stop - start")
    return np.linspace(start, stop, count).astype(np.float32)


def _lift(depths: np.ndarray, rays: np.ndarray) -> np.ndarray:
    d = np.asarray(depths, dtype=np.float64)
    return (d[:, None, None, None] * rays[None]).astype(np.float32)


def spherical_frustum(
    depths: np.ndarray,
    out_hw: tuple[int, int] = (25, 100),
    azimuth_range: tuple[float, float] = DEFAULT_AZIMUTH_RANGE,
    elevation_range: tuple[float, float] = DEFAULT_ELEVATION_RANGE,
) -> np.ndarray:
    """(D, H, W, 3) float32 points in the camera (OpenCV) frame: depth x unit ray."""
    return _lift(depths, spherical_directions(out_hw, azimuth_range, elevation_range))


def cylindrical_frustum(
    depths: np.ndarray, out_hw: tuple[int, int], azimuth_range: tuple[float, float], height_range: tuple[float, float]
) -> np.ndarray:
    """(D, H, W, 3) float32 points on cylinders of radius ``depth`` in the camera frame."""
    return _lift(depths, cylindrical_directions(out_hw, azimuth_range, height_range))


def frustum_to_lidar(frustum: np.ndarray, cam2lidar: np.ndarray) -> np.ndarray:
    """Transform one frustum (D, H, W, 3) by each camera's cam2lidar (N, 4, 4) -> (N, D, H, W, 3) float32."""
    f = np.asarray(frustum, dtype=np.float64)
    t = np.asarray(cam2lidar, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (4, 4):
        raise ValueError(f"cam2lidar: expected (N, 4, 4), got {t.shape}")
    points = np.einsum("nij,dhwj->ndhwi", t[:, :3, :3], f) + t[:, None, None, None, :3, 3]
    return points.astype(np.float32)
