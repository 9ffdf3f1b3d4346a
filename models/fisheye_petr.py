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
from typing import Any, Mapping

import numpy as np
import torch
from torch import nn

from fisheye_infer.errors import CheckpointError, ConfigError, FrameError
from fisheye_infer.geometry.frustum import depth_bins, spherical_frustum

from .backbone import FPN, ResNet
from .checkpoint import GeometryReport, KeySpec, TableCheck, as_numpy, decide_geometry
from fisheye_infer.geometry.tables import PETRParams

from .petr_config import PETRConfig
from .petr_geometry import PETRGeometry
from .petr_head import FisheyePETRHead
from .registry import register_model
from .synthetic import batchnorm_statistics, synthetic_images, temper_attention

__all__ = ["FisheyePETR", "checkpoint_filter_fn", "rename_official_keys", "calibrate", "GEOMETRY_KEYS"]

_HEAD = "pts_bbox_head."
#: Official checkpoint keys holding geometry tables (not weights of this model), in official order.
GEOMETRY_KEYS = tuple(_HEAD + k for k in ("frustum", "sphere_grid_3d", "sphere_grid_2d", "unvalid_area"))
GRID_ATOL = 1e-5  # normalised grid units (~0.004 px on an 800 px image)
MASK_ATOL = 5e-3  # sampled validity; a 1e-5 grid shift moves a lens-edge sample by at most ~4e-3
# float32 trig on float32 linspace angles (official) vs float64: up to ~1e-5 m at 48 m; a range change is >> 1e-3
FRUSTUM_RTOL, FRUSTUM_ATOL = 1e-6, 5e-5
_PRE_V2_RENAMES = ((".self_attn.", ".attentions.0."), (".multihead_attn.", ".attentions.1."),
                   (".decoder.norm.", ".decoder.post_norm."))


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


CALIBRATION_FRAMES = 2
CALIBRATION_MAX_SIDE = 320  # the head samples P3 through a normalised grid: any resolution exercises it
CLS_PRIOR_LOGIT = -4.595  # official cls bias init, bias_init_with_prob(0.01)


def calibrate(model: nn.Module, seed: int) -> None:
    """Make seeded random weights behave like a trained model's, for synthetic checkpoints.

    Reference points get the official init U(0, 1) (so boxes spread over the range instead of
    collapsing to its corners), BatchNorm statistics are collected on synthetic frames, and the
    last cls layer is affine-mapped so the median logit sits at the official prior and the top
    at prior + 3 (no sigmoid saturation, hence no score ties at the top-k boundary). The cls
    branch reads post-normed decoder features, so unit-variance features stand in for them.
    """
    cfg: PETRConfig = model.config  # type: ignore[assignment]
    head: FisheyePETRHead = model.pts_bbox_head  # type: ignore[assignment]
    gen = torch.Generator().manual_seed(int(seed) + 101)
    with torch.no_grad():
        head.reference_points.weight.copy_(torch.rand(head.reference_points.weight.shape, generator=gen))
        head.query_pos.copy_(head.query_positions())
    scale = min(1.0, CALIBRATION_MAX_SIDE / max(cfg.image_size))
    h, w = (max(32, int(round(s * scale / 32)) * 32) for s in cfg.image_size)
    frames = [synthetic_images(int(seed) * 1000 + i, 1, cfg.num_cameras, h, w) for i in range(CALIBRATION_FRAMES)]
    with batchnorm_statistics(model):
        for frame in frames:
            model.forward_features(frame)  # type: ignore[operator]
    temper_attention(model, lambda: head.forward_decoder(model.forward_features(frames[0])))  # type: ignore[operator]
    with torch.no_grad():
        feats = head.transformer.decoder.post_norm(torch.randn(cfg.num_query, cfg.embed_dims, generator=gen))
        cls, _ = head.predict(feats)
        median, top = cls.median(), cls.max()
        gain = 3.0 / float(max(top - median, 1e-3))
        final = head.cls_branches[-1][-1]
        final.weight.mul_(gain)
        final.bias.mul_(gain).add_(CLS_PRIOR_LOGIT - gain * float(median))


@register_model("fisheye-petr", config_cls=PETRConfig, manifest="fisheye_petr_keys.json", calibrate=calibrate)
class FisheyePETR(nn.Module):
    """Normalisation -> ResNet-18 -> FPN (P3 only) -> FisheyePETRHead -> NMS-free decoding.

    Missing cameras: ``camera_valid[b, n] = False`` zeroes that camera's warped features and
    masks all of its keys in cross-attention, so its pixels cannot influence any box. The
    positional embeddings stay those of the full rig: they are calibration constants baked at
    export, and the official model has no notion of a missing camera (its sine encoding counts
    cameras through the mask, so masking a camera there would shift the other cameras' keys).

    Preprocessing follows the official data preprocessor: ``(pixel - mean) / std`` per channel,
    with the RGB-ordered ImageNet statistics applied to BGR channels (``mean[0]`` to blue).
    """

    def __init__(self, config: PETRConfig | None = None, rig: Any = None,
                 geometry: PETRGeometry | None = None) -> None:
        super().__init__()
        self.config = cfg = config or PETRConfig()
        if geometry is None:
            if rig is None:
                from fisheye_infer.rig import default_rig

                rig = default_rig()
            if len(rig) != cfg.num_cameras:
                raise ConfigError(f"the rig has {len(rig)} cameras ({', '.join(rig.names)}); the configuration "
                                  f"expects {cfg.num_cameras} ({', '.join(cfg.camera_names)})")
            geometry = PETRGeometry.from_rig(rig, cfg)
        self.camera_names = tuple(rig.names) if rig is not None else cfg.camera_names
        self.rig_geometry = geometry  # recomputed tables; the reference for checkpoint comparison
        self.pts_bbox_head = FisheyePETRHead(cfg, geometry)
        self.img_backbone = ResNet(cfg.depth, cfg.strides, cfg.dilations, cfg.out_indices)
        self.img_neck = FPN(cfg.neck_in_channels, cfg.neck_out_channels, cfg.neck_num_outs)
        self.register_buffer("pixel_mean", torch.tensor(cfg.mean).reshape(1, 1, 3, 1, 1), persistent=False)
        self.register_buffer("pixel_std", torch.tensor(cfg.std).reshape(1, 1, 3, 1, 1), persistent=False)
        self.eval()

    # -- forward --------------------------------------------------------------------------

    def normalize(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 B x N x H x W x 3 (BGR) -> float B x N x 3 x H x W, normalised as in training."""
        x = images.to(torch.float32).permute(0, 1, 4, 2, 3)
        if self.config.channel_order == "RGB":
            x = x[:, :, [2, 1, 0]]
        return (x - self.pixel_mean) / self.pixel_std

    def forward_features(self, images: torch.Tensor) -> torch.Tensor:
        """uint8 images B x N x H x W x 3 -> P3 B x N x C x H/16 x W/16 (FPN level 0 only)."""
        b, n = images.shape[:2]
        x = self.normalize(images)
        p3 = self.img_neck(self.img_backbone(x.reshape(b * n, *x.shape[2:])))[0]
        return p3.reshape(b, n, *p3.shape[1:])

    def forward(self, images: torch.Tensor, camera_valid: torch.Tensor | None = None,
                cam2lidar: Any = None, tables: dict[str, torch.Tensor] | None = None) -> dict[str, torch.Tensor]:
        """images uint8 (B, N, H, W, 3) BGR, camera_valid bool (B, N) -> dict of

        boxes (B, 300, 7) [x, y, z_bottom, dx, dy, dz, yaw] lidar frame, scores (B, 300),
        labels (B, 300) int64, valid (B, 300) bool (centre inside post_center_range).
        ``cam2lidar`` (B, N, 4, 4) recomputes the 3D position embedding per frame (untraceable);
        ``tables`` replaces the installed geometry tables (the exporter passes them as graph inputs).
        """
        self._check_inputs(images, camera_valid)
        return self.pts_bbox_head(self.forward_features(images), camera_valid, cam2lidar, tables)

    def geometry_tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables the exported graph holds as named initializers."""
        return self.pts_bbox_head.tables()

    def geometry_params(self) -> PETRParams:
        """The parameters that define the geometry tables (what a re-baked file recomputes them from)."""
        return self.pts_bbox_head.params()

    def _check_inputs(self, images: torch.Tensor, camera_valid: torch.Tensor | None) -> None:
        n, (h, w) = self.config.num_cameras, self.config.image_size
        if images.dim() != 5 or tuple(images.shape[1:]) != (n, h, w, 3):
            raise FrameError(f"images: expected (B, {n}, {h}, {w}, 3) BGR, got {tuple(images.shape)}")
        if camera_valid is not None and tuple(camera_valid.shape) != (images.shape[0], n):
            raise FrameError(f"camera_valid: expected ({images.shape[0]}, {n}), got {tuple(camera_valid.shape)}")

    def set_geometry(self, geometry: PETRGeometry) -> None:
        """Install other geometry tables (same configuration) and refresh the cached embeddings."""
        self.pts_bbox_head.set_geometry(geometry)

    # -- official checkpoint ----------------------------------------------------------------

    def official_geometry_specs(self) -> dict[str, KeySpec]:
        fh, fw = self.config.feature_size
        d, f32 = self.config.num_frustum_depths, torch.float32
        return {GEOMETRY_KEYS[0]: ((d, fh, fw, 3), f32), GEOMETRY_KEYS[1]: ((d, fh, fw, 3), f32),
                GEOMETRY_KEYS[2]: ((fh, fw, 2), f32), GEOMETRY_KEYS[3]: ((1, 1, fh, fw), f32)}

    def official_keys(self) -> dict[str, KeySpec]:
        """All official keys in checkpoint order: the geometry tables follow ``code_weights``."""
        out: dict[str, KeySpec] = {}
        for key, value in self.state_dict().items():
            out[key] = (tuple(value.shape), value.dtype)
            if key == _HEAD + "code_weights":
                out.update(self.official_geometry_specs())
        return out

    def checkpoint_filter_fn(self, state_dict: Mapping[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        return checkpoint_filter_fn(state_dict)

    def _official_tables(self, geometry: PETRGeometry) -> dict[str, np.ndarray]:
        cfg = self.config
        frustum = spherical_frustum(depth_bins(cfg.dbound), cfg.feature_size, cfg.azimuth_range, cfg.elevation_range)
        grid = np.asarray(geometry.grid, dtype=np.float32)
        # world2cam depends only on the ray direction, so every depth slice holds the same grid.
        grid3d = np.concatenate([np.broadcast_to(grid, (frustum.shape[0], *grid.shape)),
                                 np.zeros((*frustum.shape[:3], 1), np.float32)], axis=-1)
        mask = np.asarray(geometry.unvalid_area, dtype=np.float32).reshape(1, 1, *grid.shape[:2])
        return dict(zip(GEOMETRY_KEYS, (frustum, np.ascontiguousarray(grid3d), grid, mask)))

    def official_state_dict(self) -> dict[str, torch.Tensor]:
        """This model's weights and geometry under the official names, in official order."""
        weights = self.state_dict()
        tables = {k: torch.from_numpy(np.array(v)) for k, v in self._official_tables(self.pts_bbox_head.geometry).items()}
        return {k: (tables[k] if k in tables else weights[k]).detach().clone() for k in self.official_keys()}

    def apply_checkpoint_geometry(self, state_dict: Mapping[str, torch.Tensor], policy: str) -> GeometryReport:
        """Compare the stored grid, mask and frustum with the rig's and install what ``policy`` selects.

        ``sphere_grid_3d`` is dead at inference and, in float32 official tables, some horizon
        cells flip to the out-of-view sentinel at some depths, so only its slice 0 is checked,
        against ``sphere_grid_2d`` (the official buffer is that slice).
        """
        stored = {k: as_numpy(state_dict[k]) for k in GEOMETRY_KEYS}
        grid2d, grid3d = stored[GEOMETRY_KEYS[2]], stored[GEOMETRY_KEYS[1]]
        if not np.array_equal(grid3d[0, ..., :2], grid2d):
            raise CheckpointError(f"{GEOMETRY_KEYS[2]} is not {GEOMETRY_KEYS[1]}[0, ..., :2]; the checkpoint's "
                                  "geometry tables are inconsistent")
        ref = self.rig_geometry
        tables = self._official_tables(ref)
        checks = (TableCheck(GEOMETRY_KEYS[2], grid2d, tables[GEOMETRY_KEYS[2]], atol=GRID_ATOL),
                  TableCheck(GEOMETRY_KEYS[3], stored[GEOMETRY_KEYS[3]], tables[GEOMETRY_KEYS[3]], atol=MASK_ATOL),
                  TableCheck(GEOMETRY_KEYS[0], stored[GEOMETRY_KEYS[0]], tables[GEOMETRY_KEYS[0]],
                             atol=FRUSTUM_ATOL, rtol=FRUSTUM_RTOL))
        source = decide_geometry(checks, policy, context="FisheyePETR checkpoint")
        geometry = ref.with_tables(grid=grid2d, unvalid_area=stored[GEOMETRY_KEYS[3]]) if source == "checkpoint" else ref
        self.set_geometry(geometry)
        return GeometryReport(source, checks)
