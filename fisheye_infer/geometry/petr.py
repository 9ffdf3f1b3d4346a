"""PETR's 3D position coordinates: the input of its position encoder, for a fixed rig.

FisheyePETR embeds each key (camera, row, column of the angular grid) by the lidar-frame
points of its ray at 64 linear-increasing depths (LID), normalised by ``position_range`` and
mapped through a clamped inverse sigmoid. None of this depends on the image, so for a fixed
rig the whole table is a constant.
"""

from __future__ import annotations

import numpy as np

from fisheye_infer.geometry.grids import DEFAULT_AZIMUTH_RANGE, DEFAULT_ELEVATION_RANGE, spherical_directions

__all__ = ["DEFAULT_POSITION_RANGE", "lid_depths", "inverse_sigmoid", "position_coords", "sine_frequencies", "sine_position_encoding"]

#: x_min, y_min, z_min, x_max, y_max, z_max in metres (lidar frame).
DEFAULT_POSITION_RANGE = (-60.0, -60.0, -10.0, 60.0, 60.0, 10.0)


def lid_depths(depth_num: int = 64, depth_start: float = 0.5, depth_max: float = 60.0) -> np.ndarray:
    """Linear-increasing depths d_i = start + beta * i * (i + 1), beta = (max - start) / (D (D + 1)).

    The far end is ``position_range[3]`` in the official code (60 m), not the LSS ``dbound``.
    """
    i = np.arange(depth_num, dtype=np.float64)
    beta = (depth_max - depth_start) / (depth_num * (1 + depth_num))
    return (depth_start + beta * i * (i + 1)).astype(np.float32)


def inverse_sigmoid(x: np.ndarray, eps: float = 1e-5) -> np.ndarray:
    """log(x / (1 - x)) after clamping x to [0, 1] and both terms to at least eps (mmdet's form)."""
    x = np.clip(x, 0.0, 1.0)
    return np.log(np.maximum(x, eps) / np.maximum(1.0 - x, eps))


def position_coords(
    cam2lidar: np.ndarray,
    out_hw: tuple[int, int] = (25, 100),
    azimuth_range: tuple[float, float] = DEFAULT_AZIMUTH_RANGE,
    elevation_range: tuple[float, float] = DEFAULT_ELEVATION_RANGE,
    depths: np.ndarray | None = None,
    position_range: tuple[float, ...] = DEFAULT_POSITION_RANGE,
    directions: np.ndarray | None = None,
) -> np.ndarray:
    """(N, 3 * D, H, W) float32: inverse-sigmoid normalised lidar points, channel 3 * i + axis.

    ``directions`` (H, W, 3) overrides the equirectangular rays (for cylindrical variants).
    """
    t = np.asarray(cam2lidar, dtype=np.float64)
    if t.ndim != 3 or t.shape[1:] != (4, 4):
        raise ValueError(f"cam2lidar: expected (N, 4, 4), got {t.shape}")
    d = np.asarray(lid_depths() if depths is None else depths, dtype=np.float64)
    rays = spherical_directions(out_hw, azimuth_range, elevation_range) if directions is None else np.asarray(directions, np.float64)
    pts = d[:, None, None, None] * rays[None]  # D x H x W x 3, camera frame
    lidar = np.einsum("nij,dhwj->ndhwi", t[:, :3, :3], pts) + t[:, None, None, None, :3, 3]  # N x D x H x W x 3
    lo = np.asarray(position_range[:3], dtype=np.float64)
    hi = np.asarray(position_range[3:], dtype=np.float64)
    coords = inverse_sigmoid((lidar - lo) / (hi - lo))
    n, dd, h, w, _ = coords.shape
    return coords.transpose(0, 1, 4, 2, 3).reshape(n, dd * 3, h, w).astype(np.float32)


def sine_frequencies(num_feats: int = 128, temperature: float = 10000.0) -> np.ndarray:
    """(num_feats,) float32 divisors t_k = temperature ** (2 floor(k / 2) / num_feats)."""
    k = np.arange(num_feats, dtype=np.float32)
    return (np.float32(temperature) ** (2 * np.floor(k / 2) / np.float32(num_feats))).astype(np.float32)


def _blocked_sin_cos(a: np.ndarray, dim_t: np.ndarray) -> np.ndarray:
    """(...,) -> (..., F): the sines of the even frequencies, then the cosines of the odd ones.

    The official ``SinePositionalEncoding3D`` stacks the two halves on a new axis *before* the
    frequency axis and flattens, so the halves are blocked, not interleaved (unlike the query
    encoding ``pos2posemb3d``, which stacks after it).
    """
    p = a[..., None] / dim_t
    return np.concatenate((np.sin(p[..., 0::2]), np.cos(p[..., 1::2])), axis=-1)


def sine_position_encoding(mask: np.ndarray, num_feats: int = 128, temperature: float = 10000.0, eps: float = 1e-6, scale: float = 2 * np.pi) -> np.ndarray:
    """PETR's 3D sine encoding of a key mask (N, H, W), True = ignored -> (N, 3 * num_feats, H, W) float32.

    Counts of valid cells accumulate (float32) along cameras, rows and columns, are normalised
    by the last count (+ eps) times ``scale``, and each is encoded as F/2 sines followed by F/2
    cosines (blocked layout); the three encodings are in the order (camera, row, column).
    """
    valid = 1.0 - np.asarray(mask, dtype=np.float32)
    n = np.cumsum(valid, axis=0, dtype=np.float32)
    y = np.cumsum(valid, axis=1, dtype=np.float32)
    x = np.cumsum(valid, axis=2, dtype=np.float32)
    eps32, scale32 = np.float32(eps), np.float32(scale)
    n = n / (n[-1:] + eps32) * scale32
    y = y / (y[:, -1:] + eps32) * scale32
    x = x / (x[:, :, -1:] + eps32) * scale32
    dim_t = sine_frequencies(num_feats, temperature)
    pe = np.concatenate([_blocked_sin_cos(v, dim_t) for v in (n, y, x)], axis=-1)  # N x H x W x 3F
    return pe.transpose(0, 3, 1, 2).astype(np.float32)
