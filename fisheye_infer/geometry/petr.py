"""FisheyePETR's geometry: the warp grid, the key mask and the key position embedding.

FisheyePETR embeds each key (camera, row, column of the angular grid) by the lidar-frame
points of its ray at 64 linear-increasing depths (LID), normalised by ``position_range`` and
mapped through a clamped inverse sigmoid (`position_coords`), passed through the head's
position encoder, plus the sine encoding of the key mask through ``adapt_pos3d``
(`key_position_embedding`). None of this depends on the image, so for a fixed rig and
fixed weights the whole table is a constant.

    geometry = PETRGeometry.from_rig(rig, params)
    geometry.tables(weights)     # {"geom.warp.*", "geom.petr.key_pos", "geom.petr.key_mask"}
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Literal, Protocol

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.grids import (
    DEFAULT_AZIMUTH_RANGE,
    DEFAULT_ELEVATION_RANGE,
    require_poses,
    sample_bilinear,
    spherical_directions,
    spherical_lens_grids,
    stored_for_first_lens,
)
from fisheye_infer.geometry.tables import PETR_KEY_MASK, WARP, Params, key_mask_table, key_tables, sampling_tables

__all__ = [
    "DEFAULT_POSITION_RANGE",
    "PETRParams",
    "PETRGeometry",
    "lid_depths",
    "inverse_sigmoid",
    "position_coords",
    "sine_frequencies",
    "sine_position_encoding",
    "KeyParams",
    "EmbeddingParams",
    "key_coords",
    "key_position_embedding",
    "remasked_key_embedding",
    "check_tables",
]

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
    rays = (
        spherical_directions(out_hw, azimuth_range, elevation_range)
        if directions is None
        else np.asarray(directions, np.float64)
    )
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


def sine_position_encoding(
    mask: np.ndarray, num_feats: int = 128, temperature: float = 10000.0, eps: float = 1e-6, scale: float = 2 * np.pi
) -> np.ndarray:
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


class KeyParams(Protocol):
    """What the key embedding reads from a PETR parameter kind (spherical or cylindrical)."""

    @property
    def feature_size(self) -> tuple[int, int]: ...
    @property
    def azimuth_range(self) -> tuple[float, float]: ...
    @property
    def elevation_range(self) -> tuple[float, float]: ...
    @property
    def depth_num(self) -> int: ...
    @property
    def depth_start(self) -> float: ...
    @property
    def position_range(self) -> tuple[float, float, float, float, float, float]: ...
    @property
    def num_feats(self) -> int: ...
    @property
    def temperature(self) -> float: ...
    def directions(self) -> np.ndarray | None: ...


class PETRParams(Params):
    kind: Literal["petr"] = "petr"
    depth_num: int
    depth_start: float
    position_range: tuple[float, float, float, float, float, float]
    num_feats: int = 128
    temperature: float = 10000.0

    def directions(self) -> np.ndarray | None:
        """(H, W, 3) rays of the keys; ``None``: the equirectangular rays of the ranges."""
        return None


def _conv_mlp(x: np.ndarray, w1: np.ndarray, b1: np.ndarray, w2: np.ndarray, b2: np.ndarray) -> np.ndarray:
    """Conv1x1 -> ReLU -> Conv1x1 over (N, Cin, H, W), in float64, as matrix products (BLAS, which ``np.einsum``
    does not call for this contraction)."""
    n, c, h, w = x.shape
    hidden = np.maximum(w1.reshape(w1.shape[0], -1) @ x.reshape(n, c, h * w) + b1[None, :, None], 0.0)
    return (w2.reshape(w2.shape[0], -1) @ hidden + b2[None, :, None]).reshape(n, -1, h, w)


def key_coords(cam2lidar: np.ndarray, params: KeyParams) -> np.ndarray:
    """(N, 3 * depth_num, H, W) float32 inputs of the position encoder for extrinsics (N, 4, 4)."""
    depths = lid_depths(params.depth_num, params.depth_start, params.position_range[3])
    t = np.asarray(cam2lidar, dtype=np.float64).reshape(-1, 4, 4)
    directions = params.directions()
    if directions is None:
        return position_coords(
            t, params.feature_size, params.azimuth_range, params.elevation_range, depths, params.position_range
        )
    return position_coords(
        t, params.feature_size, depths=depths, position_range=params.position_range, directions=directions
    )


class EmbeddingParams(Protocol):
    """What the key embedding's sine encoding reads from a parameter kind."""

    @property
    def num_feats(self) -> int: ...
    @property
    def temperature(self) -> float: ...


def _mlp(x: np.ndarray, weights: dict[str, np.ndarray], name: str) -> np.ndarray:
    """``name``'s two 1x1 convolutions (``name.{0,2}.{weight,bias}``) on (N, C, H, W), in float64."""
    w = [np.asarray(weights[f"{name}.{i}.{k}"], np.float64) for i in (0, 2) for k in ("weight", "bias")]
    return _conv_mlp(np.asarray(x, np.float64), *w)


def _as_keys(embedding: np.ndarray) -> np.ndarray:
    """(N, C, H, W) -> (1, N*H*W, C)."""
    return embedding.transpose(0, 2, 3, 1).reshape(1, -1, embedding.shape[1])


def _mask_embedding(mask: np.ndarray, n: int, weights: dict[str, np.ndarray], params: EmbeddingParams) -> np.ndarray:
    """(1, N*H*W, C) float64: adapt_pos3d(sine(mask)), the key embedding's share that depends on the mask."""
    key_mask = np.broadcast_to(np.asarray(mask) != 0, (n, *mask.shape[-2:]))
    sine = sine_position_encoding(key_mask, params.num_feats, params.temperature)
    return _as_keys(_mlp(sine, weights, "adapt_pos3d"))


def key_position_embedding(
    coords: np.ndarray, mask: np.ndarray, weights: dict[str, np.ndarray], params: EmbeddingParams
) -> np.ndarray:
    """(1, N*H*W, C) key embedding: position_encoder(coords) + adapt_pos3d(sine(mask)).

    ``weights`` holds ``position_encoder.{0,2}.{weight,bias}`` and ``adapt_pos3d.{0,2}.{weight,bias}``.
    """
    pe = _as_keys(_mlp(coords, weights, "position_encoder"))
    return (pe + _mask_embedding(mask, coords.shape[0], weights, params)).astype(np.float32)


def remasked_key_embedding(
    key_pos: np.ndarray, mask: np.ndarray, new_mask: np.ndarray, weights: dict[str, np.ndarray], params: EmbeddingParams
) -> np.ndarray:
    """A key embedding (1, N*H*W, C) computed with ``mask`` (N, H, W), moved to ``new_mask``: its mask share
    replaced, its position share kept as it is (a checkpoint's own, where the file was exported from one).

    Args:
        key_pos: The embedding a file holds.
        mask: The key mask it was computed with.
        new_mask: The key mask to move it to.
        weights: The ``adapt_pos3d`` weights (see `key_position_embedding`).
        params: The sine encoding's parameters.

    Returns:
        np.ndarray: (1, N*H*W, C) float32; ``key_pos`` itself where the masks are equal.
    """
    if np.array_equal(np.asarray(mask) != 0, np.asarray(new_mask) != 0):
        return np.asarray(key_pos, np.float32)
    n = mask.shape[0]
    moved = np.asarray(key_pos, np.float64) - _mask_embedding(mask, n, weights, params)
    return (moved + _mask_embedding(new_mask, n, weights, params)).astype(np.float32)


def check_tables(tables: dict[str, tuple[int, ...]], arrays: dict[str, np.ndarray]) -> None:
    """Raise ``ConfigError`` naming the table whose shape is not the expected one, or that is not finite."""
    for name, shape in tables.items():
        value = arrays[name]
        if tuple(np.shape(value)) != tuple(shape):
            raise ConfigError(f"geometry {name}: expected shape {tuple(shape)}, got {tuple(np.shape(value))}")
        if not np.all(np.isfinite(value)):
            raise ConfigError(f"geometry {name}: contains NaN or infinite values")


@dataclass(frozen=True)
class PETRGeometry:
    """grid (N, H, W, 2) float32, each camera's for grid_sample(align_corners=True); unvalid_area (N, H, W)
    float32, a camera's key is masked where it is not exactly 0; cam2lidar (N, 4, 4) in the model's camera order."""

    params: PETRParams
    grid: np.ndarray
    unvalid_area: np.ndarray
    cam2lidar: np.ndarray
    source: str = "rig"  # where grid and mask came from: "rig" or "checkpoint"

    @classmethod
    def from_rig(cls, rig: Rig, params: PETRParams) -> PETRGeometry:
        """Each camera's grid and mask from its lens model, extrinsics in rig order."""
        grid, mask = spherical_lens_grids(rig, params.feature_size, params.azimuth_range, params.elevation_range)
        return cls(params=params, grid=grid, unvalid_area=mask, cam2lidar=rig.cam2lidar())

    def with_lenses(self, rig: Rig) -> PETRGeometry:
        """The same extrinsics with ``rig``'s lens models: the grid and key mask of cameras calibrated anew (a
        lens centre moved); the keys' 3D coordinates depend on the poses alone."""
        require_poses(rig, self.cam2lidar, "PETRGeometry.from_rig")
        p = self.params
        grid, mask = spherical_lens_grids(rig, p.feature_size, p.azimuth_range, p.elevation_range)
        return replace(self, grid=grid, unvalid_area=mask, source="rig")

    @property
    def inside_lens(self) -> np.ndarray:
        """(N, H, W) bool: the keys attention uses (``key_mask`` False)."""
        return ~self.key_mask()

    def with_tables(
        self, *, grid: np.ndarray | None = None, unvalid_area: np.ndarray | None = None, source: str = "checkpoint"
    ) -> PETRGeometry:
        """Same extrinsics with a checkpoint's one grid (H, W, 2) and/or mask (H, W) in place of the first camera's
        lens's (`stored_for_first_lens`)."""
        new_grid = self.grid if grid is None else stored_for_first_lens(self.grid, grid)
        new_mask = self.unvalid_area if unvalid_area is None else stored_for_first_lens(self.unvalid_area, unvalid_area)
        return replace(self, grid=new_grid, unvalid_area=new_mask, source=source)

    def with_key_mask(self, key_mask: np.ndarray) -> PETRGeometry:
        """The same geometry with the keys ``key_mask`` marks masked, whatever the lenses say: a file's own key mask
        (a checkpoint's stored table where the file was exported from it).

        Args:
            key_mask: (N, H, W) bool, True where attention ignores the key.

        Returns:
            PETRGeometry: The unvalid area 1.0 on the masked keys, 0.0 elsewhere.

        Raises:
            ConfigError: ``key_mask`` is not one (H, W) mask per camera.
        """
        mask = np.asarray(key_mask, bool)
        if mask.shape != self.unvalid_area.shape:
            raise ConfigError(f"key mask: expected shape {self.unvalid_area.shape}, got {mask.shape}")
        return replace(self, unvalid_area=mask.astype(np.float32))

    def with_unseen(self, unseen: np.ndarray) -> PETRGeometry:
        """The same geometry with the keys that sample ``unseen`` image pixels masked too: a virtual camera's
        pixels that its robot camera does not see ([`fisheye_infer.geometry.virtual`][fisheye_infer.geometry.virtual]).

        Args:
            unseen: (N, H, W) bool, per camera, the image pixels without a picture.

        Returns:
            PETRGeometry: The unvalid area raised to the sampled share of unseen pixels where that is larger.
        """
        sampled = np.stack([sample_bilinear(np.asarray(u, np.float32), g) for u, g in zip(unseen, self.grid)])
        return replace(self, unvalid_area=np.maximum(self.unvalid_area, sampled).astype(np.float32))

    def check(self, num_cameras: int) -> None:
        """Raise ``ConfigError`` naming the table whose shape does not fit the parameters and camera count."""
        fh, fw = self.params.feature_size
        check_tables(
            {"grid": (num_cameras, fh, fw, 2), "unvalid_area": (num_cameras, fh, fw), "cam2lidar": (num_cameras, 4, 4)},
            {"grid": self.grid, "unvalid_area": self.unvalid_area, "cam2lidar": self.cam2lidar},
        )

    def key_mask(self) -> np.ndarray:
        """(N, H, W) bool: keys attention ignores (the camera's sampled lens validity is not exactly 1.0)."""
        return np.asarray(self.unvalid_area, np.float32) != 0

    def coords(self, cam2lidar: np.ndarray | None = None) -> np.ndarray:
        """(N, 3 * depth_num, H, W) float32 position-encoder inputs; ``cam2lidar`` overrides the rig's."""
        return key_coords(self.cam2lidar if cam2lidar is None else cam2lidar, self.params)

    def key_pos(self, weights: dict[str, np.ndarray], coords: np.ndarray | None = None) -> np.ndarray:
        """(1, N*H*W, C) float32 key embedding with ``weights`` (see `key_position_embedding`)."""
        return key_position_embedding(
            self.coords() if coords is None else coords, self.key_mask(), weights, self.params
        )

    def tables(self, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Every ``geom.*`` table of the graph; the key embedding needs the position-encoder weights."""
        if weights is None:
            raise ConfigError("weights: FisheyePETR's tables need the position_encoder and adapt_pos3d weights")
        return {**self.sampling_tables(), **key_tables(self.key_pos(weights), self.key_mask())}

    def sampling_tables(self) -> dict[str, np.ndarray]:
        """The feature warp's taps (``geom.warp.*``) on the ``source_size`` image features."""
        return sampling_tables(WARP, self.grid, self.params.source_size)

    def lens_tables(self) -> dict[str, np.ndarray]:
        """The tables a change of lens calibration replaces (a training step's moved lenses): the warp's taps and
        the key mask. The key embedding changes too (its sine encoding counts the masked keys); it needs the
        position encoder's weights."""
        return {**self.sampling_tables(), PETR_KEY_MASK: key_mask_table(self.key_mask())}
