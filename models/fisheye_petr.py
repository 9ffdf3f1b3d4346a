"""FisheyePETR in plain PyTorch: uint8 BGR fisheye images in, 300 lidar-frame boxes out.

    model = create_model("fisheye-petr", PETRConfig(), rig)
    sd, meta = load_checkpoint("fisheye_petr.pth")
    load_official_state_dict(model, sd)            # strict keys, shared-branch check, geometry policy
    out = model(images_uint8, camera_valid)        # B x N x H x W x 3 uint8 BGR, B x N bool
    out["boxes"]   # B x 300 x 7  [x, y, z_bottom, dx, dy, dz, yaw], lidar frame (x fwd, y left, z up)

Module names are the official ones (``pts_bbox_head`` first, then ``img_backbone`` and
``img_neck``). The official checkpoint's four geometry tensors are not weights here: they are
compared with the rig's recomputation and installed through ``apply_checkpoint_geometry``.
"""

from __future__ import annotations

import re
from collections.abc import Mapping
from typing import Any, ClassVar

import numpy as np
import torch

from fisheye_infer.errors import CheckpointError
from fisheye_infer.geometry.frustum import depth_bins, spherical_frustum
from fisheye_infer.geometry.petr import PETRGeometry

from .backbone import FPN, ResNet
from .base import FisheyeDetector
from .checkpoint import GeometryReport, KeySpec, TableCheck, as_numpy, decide_geometry, warn_of_other_lenses
from .normalise import normalise_frames
from .petr_config import PETRConfig
from .petr_head import INT8_FLOAT, SCORE_SEMANTICS, AnyPETRGeometry, FisheyePETRHead, decode_predictions
from .registry import register_model

__all__ = ["FisheyePETR", "checkpoint_filter_fn", "rename_official_keys", "GEOMETRY_KEYS", "SIGNATURE_KEYS"]

_HEAD = "pts_bbox_head."
#: Official checkpoint keys holding geometry tables (not weights of this model), in official order.
GEOMETRY_KEYS = tuple(_HEAD + k for k in ("frustum", "sphere_grid_3d", "sphere_grid_2d", "unvalid_area"))
GRID_ATOL = 1e-5  # normalised grid units (~0.004 px on an 800 px image)
MASK_ATOL = 5e-3  # sampled validity; a 1e-5 grid shift moves a lens-edge sample by at most ~4e-3
# float32 trig on float32 linspace angles (official) vs float64: up to ~1e-5 m at 48 m; a range change is >> 1e-3
FRUSTUM_RTOL, FRUSTUM_ATOL = 1e-6, 5e-5
#: Keys every FisheyePETR-family checkpoint holds; the spherical one also ``sphere_grid_2d``.
SIGNATURE_KEYS = (_HEAD + "position_encoder.0.weight", _HEAD + "query_embedding.0.weight")
_PRE_V2_RENAMES = (
    (".self_attn.", ".attentions.0."),
    (".multihead_attn.", ".attentions.1."),
    (".decoder.norm.", ".decoder.post_norm."),
)


def rename_official_keys(state_dict: Mapping[str, Any]) -> dict[str, Any]:
    """Unwrap ``{'state_dict': ...}``, strip a DDP ``module.`` prefix and apply the head's pre-v2
    renames (``self_attn``/``multihead_attn``/``decoder.norm``), as the official head does."""
    if "state_dict" in state_dict and isinstance(state_dict["state_dict"], Mapping):
        state_dict = state_dict["state_dict"]
    out: dict[str, Any] = {}
    for key, value in state_dict.items():
        new = re.sub(r"^module\.", "", str(key))
        if new.startswith(_HEAD + "transformer."):
            for old, rep in _PRE_V2_RENAMES:
                new = new.replace(old, rep)
        if new in out:
            raise CheckpointError(f"checkpoint key '{key}' maps to '{new}', which another key already uses")
        out[new] = value
    return out


def checkpoint_filter_fn(state_dict: Mapping[str, Any]) -> dict[str, Any]:
    """Official checkpoint -> this model's state dict: official names, geometry tables removed.

    Nothing else is dropped, so a strict load names every missing or unexpected key.
    """
    return {k: v for k, v in rename_official_keys(state_dict).items() if k not in GEOMETRY_KEYS}


@register_model(
    "fisheye-petr",
    manifest="fisheye_petr_keys.json",
    checkpoint_filter=checkpoint_filter_fn,
    signature_keys=(*SIGNATURE_KEYS, _HEAD + "sphere_grid_2d"),
    score_semantics=SCORE_SEMANTICS,
    int8_float=INT8_FLOAT,
)
class FisheyePETR(FisheyeDetector):
    """Normalisation -> ResNet-18 -> FPN (P3 only) -> FisheyePETRHead -> NMS-free decoding.

    Missing cameras: ``camera_valid[b, n] = False`` zeroes that camera's warped features and
    masks all of its keys in cross-attention, so its pixels cannot influence any box. The
    positional embeddings stay those of the full rig: they are calibration constants baked at
    export, and the official model has no notion of a missing camera (its sine encoding counts
    cameras through the mask, so masking a camera there would shift the other cameras' keys).

    Preprocessing follows the official data preprocessor: ``(pixel - mean) / std`` per channel,
    with the RGB-ordered ImageNet statistics applied to BGR channels (``mean[0]`` to blue).
    """

    config_cls: ClassVar[type[PETRConfig]] = PETRConfig
    config: PETRConfig
    rig_geometry: AnyPETRGeometry  # what geometry_from_rig makes of the configuration's PETR parameters
    pixel_mean: torch.Tensor  # (1, 1, 3, 1, 1) buffers
    pixel_std: torch.Tensor

    def __init__(
        self, config: PETRConfig | None = None, rig: Any = None, geometry: AnyPETRGeometry | None = None
    ) -> None:
        super().__init__(config, rig, geometry)
        cfg, bb = self.config, self.config.backbone
        self.pts_bbox_head = self._build_head(cfg, self.rig_geometry)
        self.img_backbone = ResNet(bb.depth, bb.strides, bb.dilations, bb.out_indices, base_channels=bb.base_channels)
        self.img_neck = FPN(bb.neck_in_channels, bb.neck_out_channels, bb.neck_num_outs)
        self.register_buffer("pixel_mean", torch.tensor(cfg.image.mean).reshape(1, 1, 3, 1, 1), persistent=False)
        self.register_buffer("pixel_std", torch.tensor(cfg.image.std).reshape(1, 1, 3, 1, 1), persistent=False)
        self.eval()

    def _build_head(self, cfg: PETRConfig, geometry: Any) -> FisheyePETRHead:
        """The detection head (the cylindrical baseline builds its own)."""
        return FisheyePETRHead(cfg, geometry)

    # -- stages (see ``FisheyeDetector``) ---------------------------------------------------

    def normalise(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """uint8 B x N x H x W x 3 (BGR) -> float (B*N) x 3 x H x W, normalised as in training (``normalise_frames``);
        no front end, so ``tables`` is not read."""
        return normalise_frames(images, self.pixel_mean, self.pixel_std, self.config.image.bgr_to_rgb)

    def scene_features(
        self,
        feats: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
        cam2lidar: Any = None,
    ) -> torch.Tensor:
        """P3 B x V x C x h x w -> decoder output B x Q x C: the features warped onto the key grid and attended
        with the keys' 3D position embedding (recomputed per frame from ``cam2lidar``, untraceable)."""
        return self.pts_bbox_head.forward_decoder(feats, camera_valid, cam2lidar, tables=tables)

    def head_outputs(self, scene: torch.Tensor) -> dict[str, torch.Tensor]:
        """Decoder output -> the decoded detections (see ``decode_predictions``)."""
        head = self.pts_bbox_head
        cls, preds = head.predict(scene)
        return decode_predictions(cls, preds, head.select, head.cfg.post_center_range)

    def predict(
        self,
        images: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        tables: dict[str, torch.Tensor] | None = None,
        cam2lidar: Any = None,
    ) -> dict[str, torch.Tensor]:
        """As `FisheyeDetector.predict`, with ``scene_features`` and ``head_outputs`` run as one call of
        ``pts_bbox_head``: a traced graph then records their nodes under that module, the path the int8
        file's float-kept modules (``INT8_FLOAT``) are named by."""
        tables = tables or self.geometry_tables()
        feats = self.image_features(images, tables)
        out: dict[str, torch.Tensor] = self.pts_bbox_head(
            feats, self.view_valid(camera_valid, feats.shape[1]), cam2lidar, tables
        )
        return out

    def forward(
        self,
        images: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        cam2lidar: Any = None,
        tables: dict[str, torch.Tensor] | None = None,
    ) -> dict[str, torch.Tensor]:
        """images uint8 (B, N, H, W, 3) BGR, camera_valid bool (B, N) -> dict of

        boxes (B, 300, 7) [x, y, z_bottom, dx, dy, dz, yaw] lidar frame, scores (B, 300),
        labels (B, 300) int64, valid (B, 300) bool (centre inside post_center_range).
        ``cam2lidar`` (B, N, 4, 4) recomputes the 3D position embedding per frame (untraceable);
        ``tables`` replaces the installed geometry tables (the exporter passes them as graph inputs).
        """
        self._check_images(images, camera_valid)
        return self.predict(images, camera_valid, tables, cam2lidar)

    def normalize(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Deprecated: `normalise`."""
        self._deprecated("normalize", "normalise")
        return self.normalise(images, tables)

    def forward_features(self, images: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """Deprecated: `image_features`."""
        self._deprecated("forward_features", "image_features")
        return self.image_features(images, tables)

    def geometry_tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables the exported graph holds as named initializers."""
        return self.pts_bbox_head.tables()

    def table_weights(self) -> dict[str, np.ndarray]:
        """The position encoder's and adapt_pos3d's weights: the key embedding table needs them."""
        return self.pts_bbox_head.embedding_weights()

    def set_geometry(self, geometry: AnyPETRGeometry) -> None:
        """Install other geometry tables (same configuration) and refresh the cached embeddings."""
        self.pts_bbox_head.set_geometry(geometry)

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        fh, fw = self.config.head.feature_size
        d, f32 = self.config.head.num_frustum_depths, torch.float32
        return {
            GEOMETRY_KEYS[0]: ((d, fh, fw, 3), f32),
            GEOMETRY_KEYS[1]: ((d, fh, fw, 3), f32),
            GEOMETRY_KEYS[2]: ((fh, fw, 2), f32),
            GEOMETRY_KEYS[3]: ((1, 1, fh, fw), f32),
        }

    def official_keys(self) -> dict[str, KeySpec]:
        """All official keys in checkpoint order: the geometry tables follow ``code_weights``."""
        out: dict[str, KeySpec] = {}
        for key, value in self.state_dict().items():
            out[key] = (tuple(value.shape), value.dtype)
            if key == _HEAD + "code_weights":
                out.update(self.official_geometry_specs())
        return out

    def _official_tables(self, geometry: AnyPETRGeometry) -> dict[str, np.ndarray]:
        """The four official geometry tensors of the spherical head (the resampled heads store none)."""
        assert isinstance(geometry, PETRGeometry)  # ResampledPETR overrides this for its geometries
        cfg = self.config.head
        frustum = spherical_frustum(depth_bins(cfg.dbound), cfg.feature_size, cfg.azimuth_range, cfg.elevation_range)
        grid = np.asarray(geometry.grid[0], dtype=np.float32)  # one grid and mask: the first camera's
        # world2cam depends only on the ray direction, so every depth slice holds the same grid.
        grid3d = np.concatenate(
            [np.broadcast_to(grid, (frustum.shape[0], *grid.shape)), np.zeros((*frustum.shape[:3], 1), np.float32)],
            axis=-1,
        )
        mask = np.asarray(geometry.unvalid_area[0], dtype=np.float32).reshape(1, 1, *grid.shape[:2])
        return dict(zip(GEOMETRY_KEYS, (frustum, np.ascontiguousarray(grid3d), grid, mask)))

    def official_geometry_state(self) -> dict[str, torch.Tensor]:
        """The geometry tables in official form, as an official checkpoint stores them."""
        return {k: torch.from_numpy(np.array(v)) for k, v in self._official_tables(self.pts_bbox_head.geometry).items()}

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Compare the stored grid, mask and frustum with the rig's and install what ``policy`` selects.

        ``sphere_grid_3d`` is dead at inference and, in float32 official tables, some horizon
        cells flip to the out-of-view sentinel at some depths, so only its slice 0 is checked,
        against ``sphere_grid_2d`` (the official buffer is that slice).
        """
        stored = {k: as_numpy(state_dict[k]) for k in GEOMETRY_KEYS}
        grid2d, grid3d = stored[GEOMETRY_KEYS[2]], stored[GEOMETRY_KEYS[1]]
        if not np.array_equal(grid3d[0, ..., :2], grid2d):
            raise CheckpointError(
                f"{GEOMETRY_KEYS[2]} is not {GEOMETRY_KEYS[1]}[0, ..., :2]; the checkpoint's "
                "geometry tables are inconsistent"
            )
        ref = self.rig_geometry
        assert isinstance(ref, PETRGeometry)  # ResampledPETR overrides this for its geometries
        tables = self._official_tables(ref)
        checks = (
            TableCheck(GEOMETRY_KEYS[2], grid2d, tables[GEOMETRY_KEYS[2]], atol=GRID_ATOL),
            TableCheck(GEOMETRY_KEYS[3], stored[GEOMETRY_KEYS[3]], tables[GEOMETRY_KEYS[3]], atol=MASK_ATOL),
            TableCheck(
                GEOMETRY_KEYS[0],
                stored[GEOMETRY_KEYS[0]],
                tables[GEOMETRY_KEYS[0]],
                atol=FRUSTUM_ATOL,
                rtol=FRUSTUM_RTOL,
            ),
        )
        source = decide_geometry(checks, policy, context="FisheyePETR checkpoint")
        warn_of_other_lenses("FisheyePETR checkpoint", self.camera_names, ref.grid, policy)
        geometry = (
            ref.with_tables(grid=grid2d, unvalid_area=stored[GEOMETRY_KEYS[3]]) if source == "checkpoint" else ref
        )
        self.set_geometry(geometry)
        return GeometryReport(source, checks)
