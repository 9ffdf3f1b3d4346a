"""The standard PETR head's geometry (pinhole PETR baselines): image front end and key embedding from ``lidar2img``.

The official ``PETRHead.position_embeding`` places the key of feature cell (h, w) of a view at the
input pixel (w * pad_w / W, h * pad_h / H) (the padded input is the views' size: the released
configs pad to a divisor of 1), lifts it to the linear-increasing depths d (LID) as
(u d, v d, d, 1), maps it to the lidar frame with ``inv(lidar2img)``, normalises by
``position_range`` and takes the clamped inverse sigmoid: channel 3 i + axis, as FisheyePETR's
(`view_coords`). The key mask is all False (the released ``img_shape`` is the loader's,
never smaller than the input), so the sine encoding is a plain ramp. The views and their front
end are [`views`][fisheye_infer.geometry.views]'.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.petr import check_tables, inverse_sigmoid, key_position_embedding, lid_depths
from fisheye_infer.geometry.tables import key_tables
from fisheye_infer.geometry.views import (
    Perspective,
    Views,
    ViewSource,
    front_end_tables,
    perspective_image_grid,
    views_of,
)

__all__ = ["PinholePETRParams", "PinholePETRGeometry", "view_coords"]

_EPS = 1e-5  # the official position_embeding's floor on the depth that scales u, v


class PinholePETRParams(BaseModel):
    """What the tables of a pinhole PETR graph are computed from (besides the rig and the embedding weights).

    ``source_size`` (H, W) of the raw camera images, ``image_size`` (H, W) of the views (the padded
    input the key pixels are spread over), ``feature_size`` (H, W) of their stride-16 features.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    kind: Literal["pinhole_petr"] = "pinhole_petr"
    feature_size: tuple[int, int]
    image_size: tuple[int, int]
    source_size: tuple[int, int]
    views: ViewSource
    depth_num: int
    depth_start: float
    position_range: tuple[float, float, float, float, float, float]
    num_feats: int = 128
    temperature: float = 10000.0


def view_coords(lidar2img: np.ndarray, params: PinholePETRParams) -> np.ndarray:
    """(V, 3 * depth_num, H, W) float32 position-encoder inputs of the views' keys (see the module docstring)."""
    (fh, fw), (ph, pw) = params.feature_size, params.image_size
    u = np.arange(fw, dtype=np.float64) * pw / fw
    v = np.arange(fh, dtype=np.float64) * ph / fh
    d = lid_depths(params.depth_num, params.depth_start, params.position_range[3]).astype(np.float64)
    scale = np.maximum(d, _EPS)
    uu, vv, dd = np.meshgrid(u, v, d, indexing="ij")  # W x H x D, the official (w, h, d) order
    ss = np.broadcast_to(scale, dd.shape)
    pixels = np.stack([uu * ss, vv * ss, dd, np.ones_like(dd)], axis=-1)  # W x H x D x 4
    img2lidar = np.linalg.inv(np.asarray(lidar2img, np.float64))  # V x 4 x 4
    points = np.einsum("vij,whdj->vwhdi", img2lidar, pixels)[..., :3]  # V x W x H x D x 3
    lo = np.asarray(params.position_range[:3], np.float64)
    hi = np.asarray(params.position_range[3:], np.float64)
    coords = inverse_sigmoid((points - lo) / (hi - lo))
    n = coords.shape[0]
    return coords.transpose(0, 3, 4, 2, 1).reshape(n, params.depth_num * 3, fh, fw).astype(np.float32)


@dataclass(frozen=True)
class PinholePETRGeometry:
    """The views (K, pose and image transform, ``lidar2img``) and the perspective rectification grid
    (empty for pinhole cameras)."""

    params: PinholePETRParams
    views: Views
    image_grid: np.ndarray  # (N, Y * Hv, Wv, 2) remap grids of each camera's views, or (0, 0, 0, 2)
    cam2lidar: np.ndarray  # V x 4 x 4, the views'
    lidar2img: np.ndarray  # V x 4 x 4
    source: str = "rig"

    @classmethod
    def from_rig(cls, rig: Rig, params: PinholePETRParams) -> PinholePETRGeometry:
        views = views_of(rig, params.views)
        grid = (
            perspective_image_grid(rig, params.views)
            if isinstance(params.views, Perspective)
            else np.zeros((0, 0, 0, 2), np.float32)
        )
        return cls(params=params, views=views, image_grid=grid, cam2lidar=views.cam2lidar, lidar2img=views.lidar2img())

    def check(self, num_views: int) -> None:
        """Raise ``ConfigError`` naming the table whose shape does not fit the configuration's view count."""
        check_tables({"lidar2img": (num_views, 4, 4)}, {"lidar2img": self.lidar2img})

    @property
    def unvalid_area(self) -> np.ndarray:
        """(H, W) float32 zeros: no key is masked."""
        return np.zeros(self.params.feature_size, np.float32)

    def key_mask(self) -> np.ndarray:
        return np.zeros((len(self.lidar2img), *self.params.feature_size), bool)

    def coords(self, cam2lidar: np.ndarray | None = None) -> np.ndarray:
        """(V, 3 * depth_num, H, W) float32; per-frame extrinsics are not supported (the views' poses come
        from the rig)."""
        if cam2lidar is not None:
            raise ConfigError(
                "pinhole PETR: per-frame extrinsics are not supported; build the model for the frame's rig instead"
            )
        return view_coords(self.lidar2img, self.params)

    def key_pos(self, weights: dict[str, np.ndarray], coords: np.ndarray | None = None) -> np.ndarray:
        """(1, V*H*W, C) float32 key embedding with ``weights``."""
        return key_position_embedding(
            self.coords() if coords is None else coords, self.unvalid_area, weights, self.params
        )

    def sampling_tables(self) -> dict[str, np.ndarray]:
        """The front end's tables: cv2.remap's taps (perspective views) or PIL's resize and crop."""
        p = self.params
        return front_end_tables(p.views, p.source_size, p.image_size, self.image_grid if self.image_grid.size else None)

    def tables(self, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Every ``geom.*`` table of the graph; the key embedding needs the position-encoder weights."""
        if weights is None:
            raise ConfigError("weights: pinhole PETR tables need the position_encoder and adapt_pos3d weights")
        return {**self.sampling_tables(), **key_tables(self.key_pos(weights), self.key_mask())}
