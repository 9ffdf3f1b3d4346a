"""Sampling grids that warp a fisheye image (or its feature map) onto an angular grid.

Both detectors resample their stride-16 fisheye features onto an equirectangular
(azimuth x elevation) grid before lifting them to 3D. The grid stores, for every output cell,
the fisheye pixel its ray hits, normalised the way the official code does it:
``g = 2 * u / W - 1`` (divisor W, not W - 1) and then sampled with ``align_corners=True``.
That small inconsistency is baked into the trained weights, so it is reproduced here.

Angles are computed in float64 and the tables are cast to float32 once, at the end.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from fisheye_infer.cameras.camera_models import OCamModel
from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError

__all__ = [
    "DEFAULT_AZIMUTH_RANGE",
    "DEFAULT_ELEVATION_RANGE",
    "fisheye_lenses",
    "per_camera",
    "spherical_lens_grids",
    "require_poses",
    "stored_for_first_lens",
    "angular_axes",
    "spherical_directions",
    "cylindrical_directions",
    "normalise_pixels",
    "spherical_grid",
    "cylindrical_grid",
    "cylindrical_remap",
    "REMAP_SUBPIXELS",
    "remap_grid",
    "cylindrical_image_grid",
    "BilinearTaps",
    "bilinear_taps",
    "remap_taps",
    "sample_bilinear",
    "invalid_mask",
    "cells_inside_lens",
]

#: +-110 degrees: the half field of view of the Fisheye3DOD lenses.
DEFAULT_AZIMUTH_RANGE = (-math.radians(110.0), math.radians(110.0))
#: +-45 degrees of elevation (positive is down, as the camera's y axis).
DEFAULT_ELEVATION_RANGE = (-math.pi / 4, math.pi / 4)


def fisheye_lenses(rig: Rig) -> list[OCamModel]:
    """Each camera's OCam model, in rig order: the lens model the fisheye geometries project with.

    Each camera has its own (a rig of four real cameras has four calibrations; Fisheye3DOD's share one).
    """
    lenses = []
    for cam in rig.cameras:
        if not isinstance(cam.model, OCamModel):
            raise ConfigError(
                f"camera '{cam.name}': a {cam.model.type} model; the fisheye geometries project with an OCam "
                "model (`fisheye-infer rig import --ocam` fits one to Kannala-Brandt, double-sphere, EUCM and Mei "
                "calibrations)"
            )
        lenses.append(cam.model)
    return lenses


def per_camera(rig: Rig, table_of: Callable[[OCamModel], np.ndarray]) -> np.ndarray:
    """(N, ...) float32: ``table_of`` each camera's lens (`fisheye_lenses`), stacked in rig order; a lens
    shared by several cameras is computed once."""
    lenses = fisheye_lenses(rig)
    tables: dict[OCamModel, np.ndarray] = {}
    for lens in lenses:
        if lens not in tables:
            tables[lens] = np.asarray(table_of(lens), np.float32)
    return np.ascontiguousarray(np.stack([tables[lens] for lens in lenses]))


def spherical_lens_grids(
    rig: Rig, out_hw: tuple[int, int], azimuth_range: tuple[float, float], elevation_range: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Each camera's equirectangular grid (N, H, W, 2) and the share of each cell outside its lens's valid area
    (N, H, W) float32 (`invalid_mask`): the lens-dependent tables of both fisheye detectors."""
    grid = per_camera(rig, lambda lens: spherical_grid(lens, out_hw, azimuth_range, elevation_range))
    outside = np.stack([invalid_mask(lens, g) for lens, g in zip(fisheye_lenses(rig), grid)])
    return grid, outside


def require_poses(rig: Rig, cam2lidar: np.ndarray, rebuild: str) -> None:
    """Refuse ``rig`` unless its cameras sit at ``cam2lidar``: a geometry's ``with_lenses`` changes the lenses
    alone; ``rebuild`` names what builds the geometry of other poses."""
    if not np.array_equal(np.asarray(rig.cam2lidar(), np.float64), np.asarray(cam2lidar, np.float64)):
        raise ConfigError(
            f"rig '{rig.name}': its camera poses differ from the geometry's; with_lenses changes lenses only "
            f"({rebuild} builds the geometry of other poses)"
        )


def stored_for_first_lens(tables: np.ndarray, stored: np.ndarray) -> np.ndarray:
    """``tables`` (N, ...) per camera with ``stored`` in place of every camera whose table is the first camera's.

    An official checkpoint stores one table (its rig's cameras share one lens); a rig whose cameras each
    have their own lens gets it for the cameras with the first camera's lens only.
    """
    out = np.array(tables, dtype=np.float32)
    same = np.array([np.array_equal(t, tables[0]) for t in tables])
    out[same] = np.asarray(stored, np.float32).reshape(out.shape[1:])
    return out


def angular_axes(
    out_hw: tuple[int, int], azimuth_range: tuple[float, float], elevation_range: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Elevation per row (H,) and azimuth per column (W,), linspace with both ends included."""
    h, w = out_hw
    return np.linspace(*elevation_range, h), np.linspace(*azimuth_range, w)


def spherical_directions(
    out_hw: tuple[int, int],
    azimuth_range: tuple[float, float] = DEFAULT_AZIMUTH_RANGE,
    elevation_range: tuple[float, float] = DEFAULT_ELEVATION_RANGE,
) -> np.ndarray:
    """Unit rays (H, W, 3) in the camera frame: (cos el sin az, sin el, cos el cos az).

    Row 0 looks up (the camera's y axis points down), column 0 looks left.
    """
    el, az = angular_axes(out_hw, azimuth_range, elevation_range)
    el, az = np.meshgrid(el, az, indexing="ij")
    return np.stack([np.cos(el) * np.sin(az), np.sin(el), np.cos(el) * np.cos(az)], axis=-1)


def cylindrical_directions(
    out_hw: tuple[int, int], azimuth_range: tuple[float, float], height_range: tuple[float, float]
) -> np.ndarray:
    """Rays (H, W, 3) on a unit-radius cylinder: (sin az, y, cos az), y linear in [y0, y1].

    ``height_range`` is in tan(elevation) units; the official baselines pass tan of their
    elevation bounds. Rays are not unit length: their horizontal radius is 1.
    """
    h, w = out_hw
    y, az = np.meshgrid(np.linspace(*height_range, h), np.linspace(*azimuth_range, w), indexing="ij")
    return np.stack([np.sin(az), y, np.cos(az)], axis=-1)


def normalise_pixels(uv: np.ndarray, camera: OCamModel) -> np.ndarray:
    """Pixel coordinates -> grid_sample coordinates with the official divisor (W, not W - 1)."""
    size = np.array([camera.width, camera.height], dtype=np.float64)
    return uv * 2.0 / size - 1.0


def _grid_from_rays(camera: OCamModel, rays: np.ndarray) -> np.ndarray:
    shape = rays.shape[:-1]
    uv = camera.world2cam(rays.reshape(-1, 3))
    return normalise_pixels(uv, camera).reshape(*shape, 2).astype(np.float32)


def spherical_grid(
    camera: OCamModel,
    out_hw: tuple[int, int] = (25, 100),
    azimuth_range: tuple[float, float] = DEFAULT_AZIMUTH_RANGE,
    elevation_range: tuple[float, float] = DEFAULT_ELEVATION_RANGE,
) -> np.ndarray:
    """Equirectangular grid (H, W, 2) float32 for ``grid_sample(align_corners=True)``.

    Rays outside the lens's fov take the OCam sentinel pixel (-1, -1), i.e. g = -1 - 2/W, as the
    official tables do; they are partially sampled, not zeroed.
    """
    return _grid_from_rays(camera, spherical_directions(out_hw, azimuth_range, elevation_range))


def cylindrical_grid(
    camera: OCamModel, out_hw: tuple[int, int], azimuth_range: tuple[float, float], height_range: tuple[float, float]
) -> np.ndarray:
    """Cylindrical grid (H, W, 2) float32 for ``grid_sample(align_corners=True)``."""
    return _grid_from_rays(camera, cylindrical_directions(out_hw, azimuth_range, height_range))


def cylindrical_remap(
    camera: OCamModel, out_hw: tuple[int, int], azimuth_range: tuple[float, float], height_range: tuple[float, float]
) -> tuple[np.ndarray, np.ndarray]:
    """Pixel maps (map_x, map_y), each (H, W) float32, for ``cv2.remap`` of a whole fisheye image.

    This is the image-level cylindrical rectification of the cylindrical baselines.
    """
    rays = cylindrical_directions(out_hw, azimuth_range, height_range)
    uv = camera.world2cam(rays.reshape(-1, 3)).reshape(*out_hw, 2).astype(np.float32)
    return uv[..., 0].copy(), uv[..., 1].copy()


#: cv2.remap (OpenCV 4.x) rounds float maps to 1/32 px (INTER_TAB_SIZE) before bilinear sampling.
REMAP_SUBPIXELS = 32
#: Where a pixel that cv2.remap fills with the border value is sent: every bilinear tap of a
#: coordinate of -2 px lies outside the image, so grid_sample reads exactly 0 there too.
_OUTSIDE_PX = -2.0


def remap_grid(map_x: np.ndarray, map_y: np.ndarray, width: int, height: int) -> np.ndarray:
    """The ``grid_sample`` grid (H, W, 2) float32 that resamples a ``width`` x ``height`` image as
    ``cv2.remap(image, map_x, map_y, INTER_LINEAR, BORDER_CONSTANT=0)`` does.

    The cylindrical baselines rectify the raw fisheye images with ``cv2.remap`` in the data
    pipeline; an exported graph does it with GridSample (bilinear, zeros, ``align_corners=True``).
    Two details make the two agree to rounding:

    - OpenCV 4.x, the version of the official mmcv 2.x stack, converts float maps to fixed point
      with 1/32 px steps (round half to even), so the map coordinates are rounded the same way
      here. OpenCV 5.0 samples float maps unrounded; ``cv2.convertMaps(..., CV_16SC2)`` still
      gives the rounded maps of OpenCV 4.x.
    - Pixel coordinates are normalised for ``align_corners=True``, ``g = 2 u / (W - 1) - 1``
      (pixel centres at the integers, as in cv2), unlike the feature grids of this module.

    Coordinates whose taps all read the border value in cv2 (at or beyond -1 or the image size,
    which includes the OCam out-of-view sentinel (-1, -1)) are moved to -2 px, where grid_sample
    reads exactly 0 as well instead of a float-rounding sliver of pixel 0.
    """
    mx = np.asarray(map_x, dtype=np.float32)
    my = np.asarray(map_y, dtype=np.float32)
    if mx.ndim != 2 or mx.shape != my.shape:
        raise ConfigError(f"map_x, map_y: expected two (H, W) maps of one shape, got {mx.shape} and {my.shape}")
    if width < 2 or height < 2:
        raise ConfigError(f"width, height: the image must be at least 2 x 2 pixels, got {width} x {height}")
    step = float(REMAP_SUBPIXELS)
    u = np.rint(mx.astype(np.float64) * step) / step
    v = np.rint(my.astype(np.float64) * step) / step
    outside = (u <= -1) | (u >= width) | (v <= -1) | (v >= height)
    u[outside] = _OUTSIDE_PX
    v[outside] = _OUTSIDE_PX
    grid = np.stack([2.0 * u / (width - 1) - 1.0, 2.0 * v / (height - 1) - 1.0], axis=-1)
    return grid.astype(np.float32)


def cylindrical_image_grid(
    camera: OCamModel, out_hw: tuple[int, int], azimuth_range: tuple[float, float], height_range: tuple[float, float]
) -> np.ndarray:
    """(H, W, 2) float32 grid that rectifies a whole fisheye image onto a cylinder with GridSample.

    Equivalent to ``cv2.remap`` with `cylindrical_remap`'s maps (see `remap_grid`):
    output row r, column c reads the ray (sin az_c, y_r, cos az_c) with az and y linspaced over
    ``azimuth_range`` and ``height_range`` (tan of the elevation bounds), both ends included.
    Angles are used as given: the official cylindrical configs pass degrees that their code uses
    as radians, and reproducing them means passing the same numbers here.
    """
    map_x, map_y = cylindrical_remap(camera, out_hw, azimuth_range, height_range)
    return remap_grid(map_x, map_y, camera.width, camera.height)


@dataclass(frozen=True)
class BilinearTaps:
    """Bilinear resampling with a constant grid as four gathers and weights.

    Output pixel p reads source pixels ``index[4p : 4p + 4]`` (flat ``row * width + col``; nw, ne,
    sw, se) with the weights ``weight[p, 0]``. A tap outside the source has index 0 and weight 0,
    so the sum reads 0 there: ``grid_sample``'s zero padding.
    """

    index: np.ndarray  # (P * 4,) int64
    weight: np.ndarray  # (P, 1, 4) float32


def bilinear_taps(grid: np.ndarray, height: int, width: int) -> BilinearTaps:
    """The taps of ``grid_sample(x, grid, 'bilinear', 'zeros', align_corners=True)`` on a ``height`` x ``width`` source.

    ``grid`` is (h, w, 2). The arithmetic follows PyTorch's CPU kernel step by step, in float32,
    so that the weights are the ones it uses and the masks sampled at construction time in the
    official code (and their rounding artefacts) come out the same.
    """
    g = np.asarray(grid, dtype=np.float32)
    if g.ndim != 3 or g.shape[-1] != 2:
        raise ConfigError(f"grid: expected (H, W, 2), got {g.shape}")
    if height < 1 or width < 1:
        raise ConfigError(f"height, width: the sampled source must be at least 1 x 1, got {height} x {width}")
    one = np.float32(1.0)
    x = (g[..., 0] + one) * np.float32((width - 1) / 2)
    y = (g[..., 1] + one) * np.float32((height - 1) / 2)
    return _taps_at(x, y, height, width)


def remap_taps(grid: np.ndarray, height: int, width: int) -> BilinearTaps:
    """The taps ``cv2.remap`` (OpenCV 4.x) reads for a `remap_grid` grid on a ``height`` x ``width`` image.

    The grid's pixel positions are multiples of 1/32 (cv2's fixed-point maps), recovered exactly
    from the float32 grid (its rounding is below 1e-4 px); the weights are then cv2's own, products
    of two k/32 fractions, exact in float32. With integer pixel values every product and partial
    sum of the four taps is exact too, so the resampled image equals cv2's to the bit, where
    `bilinear_taps` of the same grid (PyTorch's arithmetic) misses it by up to ~0.01 grey levels.
    """
    g = np.asarray(grid, dtype=np.float64)
    if g.ndim != 3 or g.shape[-1] != 2:
        raise ConfigError(f"grid: expected (H, W, 2), got {g.shape}")
    step = float(REMAP_SUBPIXELS)
    x = np.rint((g[..., 0] + 1.0) * (width - 1) / 2 * step) / step
    y = np.rint((g[..., 1] + 1.0) * (height - 1) / 2 * step) / step
    return _taps_at(x.astype(np.float32), y.astype(np.float32), height, width)


def _taps_at(x: np.ndarray, y: np.ndarray, height: int, width: int) -> BilinearTaps:
    """Bilinear taps at float32 pixel positions (x, y), in PyTorch's float32 arithmetic and order."""
    one = np.float32(1.0)
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx = x - x0
    fy = y - y0
    wx0, wy0 = one - fx, one - fy
    weights = (wy0 * wx0, wy0 * fx, fy * wx0, fy * fx)  # nw, ne, sw, se
    x0i, y0i = x0.astype(np.int64), y0.astype(np.int64)
    index, weight = [], []
    for (dy, dx), w in zip(((0, 0), (0, 1), (1, 0), (1, 1)), weights):
        xi, yi = x0i + dx, y0i + dy
        inside = (xi >= 0) & (xi < width) & (yi >= 0) & (yi < height)
        index.append(np.where(inside, yi * width + xi, 0).reshape(-1))
        weight.append(np.where(inside, w, np.float32(0.0)).reshape(-1))
    return BilinearTaps(
        index=np.stack(index, axis=1).reshape(-1).astype(np.int64),
        weight=np.stack(weight, axis=1).astype(np.float32)[:, None, :],
    )


def sample_bilinear(image: np.ndarray, grid: np.ndarray) -> np.ndarray:
    """``grid_sample(image, grid, 'bilinear', 'zeros', align_corners=True)`` in float32.

    ``image`` is (C, H, W) or (H, W); ``grid`` is (h, w, 2). The taps are `bilinear_taps`'
    and are summed in PyTorch's order (nw, ne, sw, se), in float32.
    """
    img = np.asarray(image, dtype=np.float32)
    squeeze = img.ndim == 2
    if squeeze:
        img = img[None]
    channels, height, width = img.shape
    taps = bilinear_taps(grid, height, width)
    flat = img.reshape(channels, -1)
    index = taps.index.reshape(-1, 4)
    total: np.ndarray = np.zeros((channels, index.shape[0]), dtype=np.float32)
    for k in range(4):
        total = total + taps.weight[:, 0, k] * flat[:, index[:, k]]
    out = total.reshape(channels, *np.shape(grid)[:2])
    return out[0] if squeeze else out


def invalid_mask(camera: OCamModel, grid: np.ndarray) -> np.ndarray:
    """1 - (the lens's valid area sampled at ``grid``), (h, w) float32.

    FisheyePETR masks every key where this is not exactly 0, which includes a few interior
    cells whose bilinear weights do not sum to exactly 1.0 in float32.
    """
    valid = camera.valid_area().astype(np.float32) / np.float32(255.0)
    return np.float32(1.0) - sample_bilinear(valid, grid)


def cells_inside_lens(
    camera: OCamModel, image_grid: np.ndarray, views: int, feature_size: tuple[int, int]
) -> np.ndarray:
    """(views, fH, fW) bool: the feature cells of ``views`` images resampled from the fisheye ``camera`` with
    ``image_grid`` (the images stacked by rows, (views * H, W, 2)) whose pixels mostly show the lens's field of view,
    not the black beyond it.

    A rectified view wider than the lens holds such cells; a depth target there would teach the depth head what
    lies behind black pixels. Each feature cell covers the block of pixels of the backbone's stride (pixel row r
    in cell row ``r * fH // H``, columns alike).
    """
    fh, fw = feature_size
    valid = (np.float32(1.0) - invalid_mask(camera, image_grid)).reshape(views, -1, image_grid.shape[1])
    _, h, w = valid.shape
    rows = ((np.arange(h) * fh) // h)[None, :] == np.arange(fh)[:, None]  # fH x H: the pixel rows of each cell row
    cols = ((np.arange(w) * fw) // w)[None, :] == np.arange(fw)[:, None]  # fW x W
    share = rows.astype(np.float64) @ valid.astype(np.float64) @ cols.T.astype(np.float64)
    return share / np.outer(rows.sum(axis=1), cols.sum(axis=1)) > 0.5
