"""FisheyePETRHead: equirectangular feature warp, PETR position embeddings, decoder and box decoding.

Data path (B batch, N cameras, C = embed_dims, H x W = feature_size, Q = num_query):

    P3          B x N x C x h x w      stride-16 fisheye features (FPN level 0)
    warp        B x N x C x H x W      grid_sample on the constant spherical grid, as bilinear taps
    memory      B x (N*H*W) x C        input_proj, keys in (n, h, w) order
    key_pos     1 x (N*H*W) x C        PE3D(cam2lidar) + adapt_pos3d(sine PE of the key mask)
    decoder     B x Q x C              6 post-norm layers, post_norm on the returned output
    branches    B x Q x K, B x Q x 8   shared cls/reg branches, reference-point offsets
    decode      B x 300 x 7 ...        NMS-free top-k over Q*K sigmoid scores

Everything in ``key_pos`` and ``query_pos`` depends only on calibration and weights. It is
computed by ``position_embedding()``/``query_positions()`` and cached in non-persistent
buffers whenever the geometry is set or a state dict is loaded, so a trace sees constants; so
is the decoder's first self-attention (``PETRTransformer.cache_first_self_attention``).
Passing ``cam2lidar`` per frame takes the dynamic (numpy, untraceable) path instead.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import torch
from torch import nn

from fisheye_infer.errors import CheckpointError, ConfigError
from fisheye_infer.geometry.cyl_petr import CylPETRGeometry
from fisheye_infer.geometry.petr import PETRGeometry, sine_position_encoding
from fisheye_infer.geometry.pinhole_petr import PinholePETRGeometry
from fisheye_infer.geometry.tables import PETR_KEY_MASK, PETR_KEY_POS, WARP

from .petr_config import PETRConfig
from .petr_embedding import inverse_sigmoid, pos2posemb3d
from .petr_transformer import PETRTransformer, key_padding_bias
from .ranking import TopK
from .resample import resample, taps_for
from .table_buffers import install_tables, installed_tables

__all__ = [
    "FisheyePETRHead",
    "RectifiedPETRHead",
    "CylindricalPETRHead",
    "decode_predictions",
    "SCORE_SEMANTICS",
    "INT8_FLOAT",
]

#: The geometry objects a PETR head installs.
AnyPETRGeometry = PETRGeometry | CylPETRGeometry | PinholePETRGeometry

#: What the scores of a PETR head mean (recorded in an exported file's metadata).
SCORE_SEMANTICS = (
    "sigmoid(class logit); top boxes over queries x classes (NMS-free); no threshold, as the official test time"
)

#: Where the int8 search starts: the classification and regression branches float32 (the counterpart of
#: the TransFusion head's branches, which FisheyeBEVDet's measurement keeps float); the transformer's linear
#: layers are quantized. Not measured: no trained FisheyePETR exists, and on the checkpoint kit's
#: untrained head the top boxes' scores tie (the best five equal to three decimals), so no int8
#: scope can be judged there.
INT8_FLOAT = ("pts_bbox_head.cls_branches", "pts_bbox_head.reg_branches")


def _conv_mlp(c_in: int, c_hidden: int, c_out: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(c_in, c_hidden, 1), nn.ReLU(), nn.Conv2d(c_hidden, c_out, 1))


def _f32(a: np.ndarray) -> torch.Tensor:
    return torch.from_numpy(np.ascontiguousarray(a, dtype=np.float32))


class FisheyePETRHead(nn.Module):
    """The official ``FisheyePETRHead`` at test time, with its module names and order.

    The official geometry tensors (``frustum``, ``sphere_grid_3d``, ``sphere_grid_2d``,
    ``unvalid_area``) are not state of this module: the grid and mask are non-persistent buffers
    installed from a ``PETRGeometry`` (the rig's, or the checkpoint's after verification).

    ``cls_branches``/``reg_branches`` hold the same module six times, as the official head
    does, so a checkpoint's six copies all load (into one set of weights); a load whose copies
    differ is refused with ``CheckpointError`` naming the first differing key.
    """

    # Buffers (``register_buffer``), declared because ``nn.Module.__getattr__`` types them ``Tensor | Module``.
    code_weights: torch.Tensor
    unvalid_area: torch.Tensor
    coords3d: torch.Tensor
    key_pos: torch.Tensor
    key_mask_flat: torch.Tensor
    query_pos: torch.Tensor

    def __init__(self, config: PETRConfig, geometry: AnyPETRGeometry) -> None:
        super().__init__()
        self.config = config
        self.cfg = cfg = config.head
        c, (fh, fw) = cfg.embed_dims, cfg.feature_size
        # code_weights (all 1.0, a training constant) is the only checkpoint tensor kept as state;
        # the official geometry tensors are installed by set_geometry (see fisheye_petr.py).
        self.register_buffer("code_weights", torch.ones(cfg.code_size))
        self.input_proj = nn.Conv2d(config.backbone.neck_out_channels, c, 1)
        cls_layers: list[nn.Module] = []
        reg_layers: list[nn.Module] = []
        for _ in range(cfg.num_reg_fcs):
            cls_layers += [nn.Linear(c, c), nn.LayerNorm(c), nn.ReLU()]
            reg_layers += [nn.Linear(c, c), nn.ReLU()]
        cls_branch = nn.Sequential(*cls_layers, nn.Linear(c, config.num_classes))
        reg_branch = nn.Sequential(*reg_layers, nn.Linear(c, cfg.code_size))
        self.cls_branches = nn.ModuleList([cls_branch] * cfg.num_layers)
        self.reg_branches = nn.ModuleList([reg_branch] * cfg.num_layers)
        self.select = TopK(cfg.max_num)
        self.adapt_pos3d = _conv_mlp(c * 3 // 2, c * 4, c)
        self.position_encoder = _conv_mlp(3 * cfg.depth_num, c * 4, c)
        self.reference_points = nn.Embedding(cfg.num_query, 3)
        nn.init.uniform_(self.reference_points.weight, 0.0, 1.0)
        self.query_embedding = nn.Sequential(nn.Linear(c * 3 // 2, c), nn.ReLU(), nn.Linear(c, c))
        self.transformer = PETRTransformer(cfg.num_layers, c, cfg.num_heads, cfg.ffn_dims)

        # Calibration-derived tables and the cached embeddings: buffers, but not state-dict keys.
        n = config.num_views
        self._sampling_names: tuple[str, ...] = ()
        self.register_buffer("unvalid_area", torch.zeros(1, n, fh, fw), persistent=False)
        self.register_buffer("coords3d", torch.zeros(n, 3 * cfg.depth_num, fh, fw), persistent=False)
        self.register_buffer("key_pos", torch.zeros(1, n * fh * fw, c), persistent=False)
        self.register_buffer("key_mask_flat", torch.zeros(1, n * fh * fw, dtype=torch.bool), persistent=False)
        self.register_buffer("query_pos", torch.zeros(cfg.num_query, c), persistent=False)
        self._register_load_state_dict_pre_hook(_check_shared_branches, with_module=True)
        self.register_load_state_dict_post_hook(lambda module, _incompatible: module.refresh_embeddings())
        self.set_geometry(geometry)

    # ------------------------------------------------------------------ geometry and caches
    def _install_sampling(self, geometry: AnyPETRGeometry) -> None:
        """The resampling taps (``geom.warp.*``, or ``geom.rectify.*`` of the cylindrical head) as buffers."""
        self._sampling_names = install_tables(
            self, geometry.sampling_tables(), self._sampling_names, self.code_weights.device
        )

    def set_geometry(self, geometry: AnyPETRGeometry) -> None:
        """Install a rig's tables (warp grid, key mask, cam2lidar) and recompute the cached embeddings."""
        if tuple(geometry.params.feature_size) != tuple(self.cfg.feature_size):
            raise ConfigError(
                f"geometry feature_size {tuple(geometry.params.feature_size)} differs from the configuration's "
                f"head.feature_size {tuple(self.cfg.feature_size)}"
            )
        geometry.check(self.config.num_views)
        current = getattr(self, "geometry", None)
        if current is not None and current is not geometry and _same_tables(current, geometry):
            self.geometry = geometry  # same numbers (e.g. a checkpoint storing the rig's tables)
            return
        self.geometry = geometry
        device = self.code_weights.device
        self._install_sampling(geometry)
        self.unvalid_area.copy_(_f32(geometry.unvalid_area).expand_as(self.unvalid_area).to(device))
        self.coords3d.copy_(_f32(geometry.coords()).to(device))
        self.refresh_embeddings()

    @torch.no_grad()
    def refresh_embeddings(self) -> None:
        """Recompute ``key_pos``, ``query_pos`` and the decoder's first self-attention (which reads only weights and
        ``query_pos``) from the current weights and geometry."""
        pe = self.position_embedding()  # 1 x N x C x H x W
        self.key_pos.copy_(pe.permute(0, 1, 3, 4, 2).reshape(1, -1, self.cfg.embed_dims))
        self.key_mask_flat.copy_(self.key_mask().reshape(1, -1))
        self.query_pos.copy_(self.query_positions())
        self.transformer.cache_first_self_attention(self.query_pos)

    def key_mask(self) -> torch.Tensor:
        """(1, N, H, W) bool: True where the camera's sampled lens validity is not exactly 1.0."""
        return self.unvalid_area != 0

    def embedding_weights(self) -> dict[str, np.ndarray]:
        """The weights the key embedding needs, by name (what re-baking for a new rig needs)."""
        modules = {"position_encoder": self.position_encoder, "adapt_pos3d": self.adapt_pos3d}
        return {
            f"{name}.{k}": v.detach().cpu().numpy().copy()
            for name, m in modules.items()
            for k, v in m.state_dict().items()
        }

    def position_embedding(self, cam2lidar: Any = None) -> torch.Tensor:
        """Key positional embedding PE3D + adapt_pos3d(sine PE), (1|B, N, C, H, W).

        Computed by the geometry's ``key_pos`` from this head's weights, the one definition an
        exported file's ``geom.petr.key_pos`` also comes from. Without ``cam2lidar`` the rig's
        constant coordinates are used; with a (B, N, 4, 4) array the coordinates are recomputed
        per frame (parity path).
        """
        n, (fh, fw), c = self.config.num_views, self.cfg.feature_size, self.cfg.embed_dims
        if cam2lidar is None:
            coords = [self.coords3d.cpu().numpy()]
        else:
            mats = cam2lidar.detach().cpu().numpy() if torch.is_tensor(cam2lidar) else np.asarray(cam2lidar)
            if mats.ndim != 4 or mats.shape[1:] != (n, 4, 4):
                raise ConfigError(f"cam2lidar: expected (B, {n}, 4, 4), got {tuple(mats.shape)}")
            coords = [self.geometry.coords(m) for m in mats]
        weights = self.embedding_weights()
        pe = np.stack([self.geometry.key_pos(weights, x).reshape(n, fh, fw, c) for x in coords])
        return _f32(pe).permute(0, 1, 4, 2, 3).to(self.coords3d.device)  # B x N x C x H x W

    def trainable_positions(self, key_mask: np.ndarray | None = None) -> tuple[torch.Tensor, torch.Tensor]:
        """(key_pos (1, N*H*W, C), query_pos (Q, C)) computed by this head's torch modules, so that training
        reaches ``position_encoder``, ``adapt_pos3d``, ``query_embedding`` and ``reference_points``.

        The inputs are the geometry's numpy tables (the key coordinates and the sine encoding of the key
        mask), so the numbers are those of the cached ``key_pos``/``query_pos``; only the gradient is new.
        ``key_mask`` (N, H, W) bool replaces the installed mask (a training step's moved lenses).
        """
        p = self.geometry.params
        mask = self.key_mask()[0].cpu().numpy() if key_mask is None else np.asarray(key_mask, bool)
        sine = _f32(sine_position_encoding(mask, p.num_feats, p.temperature)).to(self.coords3d.device)
        pe = self.position_encoder(self.coords3d) + self.adapt_pos3d(sine)  # N x C x H x W
        return pe.permute(0, 2, 3, 1).reshape(1, -1, self.cfg.embed_dims), self.query_positions()

    def tables(self) -> dict[str, torch.Tensor]:
        """The ``geom.*`` tables an exported graph holds as named initializers."""
        return {
            **installed_tables(self, self._sampling_names),
            PETR_KEY_POS: self.key_pos,
            PETR_KEY_MASK: self.key_mask_flat,
        }

    def query_positions(self) -> torch.Tensor:
        """(Q, C): query_embedding(pos2posemb3d(raw reference points))."""
        return self.query_embedding(
            pos2posemb3d(self.reference_points.weight, self.cfg.embed_dims // 2, self.cfg.pe_temperature)
        )

    # ------------------------------------------------------------------ forward
    def warp(self, p3: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """B x N x C x h x w -> B x N x C x H x W on the spherical grid, each camera with its lens's taps
        (``geom.warp.*``; see [`resample`][fisheye_infer.models.resample])."""
        g = self.geometry
        assert isinstance(g, PETRGeometry)  # the spherical head's; RectifiedPETRHead has no warp
        index, weight = taps_for(tables or self.tables(), WARP, g.grid, g.params.source_size, p3.shape[-2:], p3.device)
        return resample(p3, index, weight, self.cfg.feature_size)

    def forward_decoder(
        self,
        p3: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        cam2lidar: Any = None,
        return_intermediate: bool = False,
        tables: dict[str, torch.Tensor] | None = None,
        positions: tuple[torch.Tensor, torch.Tensor] | None = None,
    ) -> torch.Tensor:
        """P3 (B, N, C, h, w) -> decoder output (B, Q, C), or (L, B, Q, C) for all layers.

        A camera with ``camera_valid`` False gets zero warped features and all its keys masked;
        the positional embeddings stay those of the full rig (they are calibration constants).
        ``positions`` (``trainable_positions()``) replaces the cached key and query embeddings.
        """
        b, n, c_in = p3.shape[:3]
        c, (fh, fw) = self.cfg.embed_dims, self.cfg.feature_size
        tables = tables or self.tables()
        x = self.warp(p3, tables)
        mask = tables[PETR_KEY_MASK].reshape(1, n, fh * fw)  # 1 x N x HW
        if camera_valid is not None:
            keep = camera_valid.to(torch.bool)[:, :, None, None, None]
            x = torch.where(keep, x, torch.zeros_like(x))
            mask = mask | ~camera_valid.to(torch.bool)[:, :, None]  # B x N x HW
        key_bias = key_padding_bias(mask.reshape(mask.shape[0], n * fh * fw))  # B|1 x K
        x = self.input_proj(x.reshape(b * n, c_in, fh, fw))
        memory = x.reshape(b, n, c, fh, fw).permute(0, 1, 3, 4, 2).reshape(b, n * fh * fw, c)
        cached = positions is None and cam2lidar is None and not self.training
        if positions is not None:
            key_pos, query_pos = positions
        elif cam2lidar is None:
            key_pos, query_pos = tables[PETR_KEY_POS], self.query_pos
        else:
            key_pos = self.position_embedding(cam2lidar).permute(0, 1, 3, 4, 2).reshape(-1, n * fh * fw, c)
            query_pos = self.query_positions()
        return self.transformer(memory, query_pos, key_pos, key_bias, return_intermediate, cached)

    def predict(self, outs_dec: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Decoder output (..., Q, C) -> class logits (..., Q, K), box preds (..., Q, 8).

        Box preds follow the official ``all_bbox_preds``: [x, y, log dx, log dy, z_c, log dz,
        sin, cos] with x, y, z_c in metres (sigmoid(offset + logit(ref)) scaled to pc_range).
        """
        cls = self.cls_branches[-1](outs_dec)
        reg = self.reg_branches[-1](outs_dec)
        ref = inverse_sigmoid(self.reference_points.weight)  # Q x 3, clamped to [0, 1] first
        pc = self.cfg.point_cloud_range
        x = torch.sigmoid(reg[..., 0:1] + ref[:, 0:1]) * (pc[3] - pc[0]) + pc[0]
        y = torch.sigmoid(reg[..., 1:2] + ref[:, 1:2]) * (pc[4] - pc[1]) + pc[1]
        z = torch.sigmoid(reg[..., 4:5] + ref[:, 2:3]) * (pc[5] - pc[2]) + pc[2]
        preds = torch.cat((x, y, reg[..., 2:4], z, reg[..., 5:8]), dim=-1)
        return cls, preds

    def forward(
        self,
        p3: torch.Tensor,
        camera_valid: torch.Tensor | None = None,
        cam2lidar: Any = None,
        tables: dict[str, torch.Tensor] | None = None,
    ) -> dict[str, torch.Tensor]:
        """P3 (B, N, C, h, w) -> decoded detections (see ``decode_predictions``)."""
        cls, preds = self.predict(self.forward_decoder(p3, camera_valid, cam2lidar, tables=tables))
        return decode_predictions(cls, preds, self.select, self.cfg.post_center_range)


class RectifiedPETRHead(FisheyePETRHead):
    """A PETR head without the feature warp: the images were resampled before the backbone (onto a
    cylinder, into perspective views, or resized and cropped), so P3 is the key grid, and the head
    holds the image front end's tables (``geom.rectify.*`` or ``geom.resize.*``) so that ``tables()``
    lists every table of the graph. Module names and order are FisheyePETRHead's; the geometry
    object says where the keys lie (a cylinder, or the views' ``lidar2img``).
    """

    def warp(self, p3: torch.Tensor, tables: dict[str, torch.Tensor] | None = None) -> torch.Tensor:
        """No feature warp: B x N x C x H x W features of the resampled images are the keys."""
        fh, fw = self.cfg.feature_size
        if tuple(p3.shape[-2:]) != (fh, fw):
            raise ConfigError(
                f"image features are {tuple(p3.shape[-2:])}, the keys need ({fh}, {fw}): "
                "the resampled images do not have the configured size"
            )
        return p3


class CylindricalPETRHead(RectifiedPETRHead):
    """The official ``CylindricalPETRHead`` at test time: no key mask, and the key rays lie on the cylinder
    ([`CylPETRGeometry`][fisheye_infer.geometry.cyl_petr.CylPETRGeometry]). State-dict keys are FisheyePETRHead's
    minus the four geometry tensors."""


def decode_predictions(
    cls: torch.Tensor,
    preds: torch.Tensor,
    select: TopK,
    post_center_range: tuple[float, ...] = (-60.0, -60.0, -10.0, 60.0, 60.0, 10.0),
) -> dict[str, torch.Tensor]:
    """NMSFreeCoder: top-k (``select``, M = select.k) of all Q*K sigmoid scores, then boxes in the lidar frame.

    cls (B, Q, K) logits and preds (B, Q, 8) -> boxes (B, M, 7) = [x, y, z_bottom, dx, dy, dz, yaw],
    scores (B, M), labels (B, M) int64, valid (B, M) bool (centre inside post_center_range; the
    official filter drops the others, here they are flagged so the output size stays M), and the
    ranking step's ``rank_scores`` (B, Q*K) / ``rank_indices`` (B, M).
    Yaw: theta' = atan2(sin, cos) is -yaw - pi/2, so yaw = -theta' - pi/2 wrapped to [-pi, pi).
    """
    b, q, k = cls.shape
    max_num = select.k
    rank_scores = select.dense(torch.sigmoid(cls).reshape(b, q * k))
    scores, idx = select(rank_scores)  # sorted, largest first
    labels = torch.remainder(idx, k)
    query = torch.div(idx, k, rounding_mode="floor")
    p = torch.gather(preds, 1, query.unsqueeze(-1).expand(b, max_num, preds.shape[-1]))  # B x M x 8
    yaw = -torch.atan2(p[..., 6:7], p[..., 7:8]) - math.pi / 2
    yaw = yaw - torch.floor(yaw / (2 * math.pi) + 0.5) * (2 * math.pi)
    dims = torch.exp(torch.cat((p[..., 2:4], p[..., 5:6]), dim=-1))  # dx, dy, dz
    centre = torch.cat((p[..., 0:2], p[..., 4:5]), dim=-1)  # gravity centre
    z_bottom = centre[..., 2:3] - dims[..., 2:3] * 0.5
    boxes = torch.cat((centre[..., 0:2], z_bottom, dims, yaw), dim=-1)
    lo, hi = post_center_range[:3], post_center_range[3:]
    valid = torch.ones_like(scores, dtype=torch.bool)
    for axis in range(3):
        valid = valid & (centre[..., axis] >= lo[axis]) & (centre[..., axis] <= hi[axis])
    return {
        "boxes": boxes,
        "scores": scores,
        "labels": labels,
        "valid": valid,
        "rank_scores": rank_scores,
        "rank_indices": idx,
    }


def _same_tables(a: AnyPETRGeometry, b: AnyPETRGeometry) -> bool:
    keys = ("grid", "unvalid_area", "cam2lidar") if isinstance(b, PETRGeometry) else ("image_grid", "cam2lidar")
    if isinstance(b, PinholePETRGeometry):
        keys = ("image_grid", "lidar2img")
    return type(a) is type(b) and all(
        np.array_equal(np.asarray(getattr(a, k), np.float64).ravel(), np.asarray(getattr(b, k), np.float64).ravel())
        for k in keys
    )


def _check_shared_branches(module: FisheyePETRHead, state_dict: dict[str, Any], prefix: str, *_args: Any) -> None:
    """Refuse a checkpoint whose copies of the shared cls/reg branch differ."""
    for name in ("cls_branches", "reg_branches"):
        head = f"{prefix}{name}."
        first = {k[len(head) + 2 :]: v for k, v in state_dict.items() if k.startswith(head + "0.")}
        for copy in range(1, len(getattr(module, name))):
            for suffix, ref in first.items():
                key = f"{head}{copy}.{suffix}"
                other = state_dict.get(key)
                if (
                    other is not None
                    and torch.is_tensor(other)
                    and torch.is_tensor(ref)
                    and (other.shape != ref.shape or not torch.equal(other, ref))
                ):
                    raise CheckpointError(
                        f"checkpoint key '{key}' differs from '{head}0.{suffix}': the official head "
                        f"shares one {name[:3]} branch across all decoder layers, so the copies must be equal"
                    )
