"""TransFusion head (its raw outputs for training, decoded boxes for inference), with the Fisheye3DOD
quirks kept and an export-safe graph.

Quirks reproduced on purpose (each changes the output of the official checkpoint):
- local-max NMS uses max_pool2d with padding 0 and zero-fills the border, so classes that are
  suppressed lose their whole 1-cell border; the Fisheye3DOD branch leaves classes 4 and 5
  (Pedestrian, Cyclist) unsuppressed;
- in both attentions the *value* includes the position embedding (q = k = v = x + pos);
- score = sigmoid(class logit) * heatmap peak, masked to the proposal's own class; label = argmax,
  so a zero product yields label 0;
- no score threshold and no NMS: all proposals are returned, with a ``valid`` mask for the
  post-centre range instead of boolean filtering (fixed output shapes).

Export notes: top-k uses ``torch.topk`` (ONNX TopK) rather than argsort; the one-hot products are
``where``/gather; there are no in-place writes, python loops over the batch or boolean indexing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from .ranking import TopK

__all__ = [
    "TransFusionHead",
    "SeparateHead",
    "TransFusionDecoderLayer",
    "PositionEncodingLearned",
    "SCORE_SEMANTICS",
    "INT8_FLOAT",
]

#: What the scores of a TransFusion head mean (recorded in an exported file's metadata).
SCORE_SEMANTICS = (
    "sigmoid(class logit) x the proposal's heatmap peak (TransFusion); no threshold, no NMS, as the official test time"
)

#: Where the int8 search starts (``fisheye_infer.export.int8_search``): the head float32, but for its
#: shared convolution and the first convolution of its heatmap branch: both are 3x3 over the whole BEV
#: grid and the head's largest layers, so quantizing them buys most of the head's speed-up; the heatmap's
#: last convolution ranks the proposals and stays float, as do the prediction heads, the decoder and the
#: class encoding.
#: ``benchmarks/int8.py --keep-float MODULE ...`` measures any other choice (FDS against fp32, the
#: share of the fp32 top-50 boxes kept, the speed-up) on the shipped model's held-out frames.
INT8_FLOAT = ("bbox_head.heatmap_head.1", "bbox_head.prediction_heads", "bbox_head.decoder", "bbox_head.class_encoding")

DEFAULT_COMMON_HEADS: dict[str, tuple[int, int]] = {"center": (2, 2), "height": (1, 2), "dim": (3, 2), "rot": (2, 2)}


class ConvBN(nn.Module):
    """mmcv ConvModule with a norm (conv without bias, BN, ReLU), stored as ``.conv`` / ``.bn``."""

    def __init__(self, cin: int, cout: int, kernel_size: int, dims: int) -> None:
        super().__init__()
        conv = nn.Conv1d if dims == 1 else nn.Conv2d
        bn = nn.BatchNorm1d if dims == 1 else nn.BatchNorm2d
        self.conv = conv(cin, cout, kernel_size, padding=kernel_size // 2, bias=False)
        self.bn = bn(cout, eps=1e-5)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(self.bn(self.conv(x)))


class PositionEncodingLearned(nn.Module):
    """Conv1d(2->C) -> BN1d -> ReLU -> Conv1d(C->C) on (x, y) grid positions."""

    def __init__(self, input_channel: int = 2, num_pos_feats: int = 128) -> None:
        super().__init__()
        self.position_embedding_head = nn.Sequential(
            nn.Conv1d(input_channel, num_pos_feats, 1),
            nn.BatchNorm1d(num_pos_feats, eps=1e-5),
            nn.ReLU(inplace=False),
            nn.Conv1d(num_pos_feats, num_pos_feats, 1),
        )

    def forward(self, xy: torch.Tensor) -> torch.Tensor:
        # xy: B x P x 2 -> B x P x C
        return self.position_embedding_head(xy.transpose(1, 2)).transpose(1, 2)


class MultiheadAttention(nn.Module):
    """Parameters laid out as nn.MultiheadAttention (packed in_proj: rows Q, K, V), batch-first maths.

    The arithmetic follows torch's need_weights path (q scaled by 1/sqrt(head_dim) before q k^T),
    written with explicit matmuls so that it exports as plain MatMul/Softmax.
    """

    def __init__(self, embed_dims: int, num_heads: int) -> None:
        super().__init__()
        self.embed_dims, self.num_heads = embed_dims, num_heads
        self.in_proj_weight = nn.Parameter(torch.empty(3 * embed_dims, embed_dims))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * embed_dims))
        self.out_proj = nn.Linear(embed_dims, embed_dims)
        nn.init.xavier_uniform_(self.in_proj_weight)

    def forward(self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        # q: B x Lq x C, k, v: B x Lk x C (k, v may broadcast over batch with a leading 1)
        c, h = self.embed_dims, self.num_heads
        w_q, w_k, w_v = self.in_proj_weight.split(c, dim=0)
        b_q, b_k, b_v = self.in_proj_bias.split(c, dim=0)
        bq, lq = q.shape[0], q.shape[1]
        qh = F.linear(q, w_q, b_q).reshape(bq, lq, h, c // h).transpose(1, 2)  # B x h x Lq x d
        kh = F.linear(k, w_k, b_k).reshape(k.shape[0], k.shape[1], h, c // h).transpose(1, 2)
        vh = F.linear(v, w_v, b_v).reshape(v.shape[0], v.shape[1], h, c // h).transpose(1, 2)
        qh = qh * math.sqrt(1.0 / float(c // h))
        attn = torch.softmax(torch.matmul(qh, kh.transpose(-2, -1)), dim=-1)  # B x h x Lq x Lk
        out = torch.matmul(attn, vh).transpose(1, 2).reshape(bq, lq, c)
        return self.out_proj(out)


class AttentionBlock(nn.Module):
    """mmcv MultiheadAttention wrapper: holds the torch-layout attention under ``.attn``."""

    def __init__(self, embed_dims: int, num_heads: int) -> None:
        super().__init__()
        self.attn = MultiheadAttention(embed_dims, num_heads)

    def forward(self, q: torch.Tensor, k: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
        return self.attn(q, k, v)


class FFN(nn.Module):
    """mmcv FFN with two fcs: ``layers.0.0`` Linear -> ReLU, ``layers.1`` Linear (dropouts are no-ops)."""

    def __init__(self, embed_dims: int, feedforward_channels: int) -> None:
        super().__init__()
        self.layers = nn.Sequential(
            nn.Sequential(nn.Linear(embed_dims, feedforward_channels), nn.ReLU(inplace=False)),
            nn.Linear(feedforward_channels, embed_dims),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(x)


class TransFusionDecoderLayer(nn.Module):
    """Post-norm decoder layer; the residual is the query before the position embedding is added."""

    def __init__(self, embed_dims: int = 128, num_heads: int = 8, feedforward_channels: int = 256) -> None:
        super().__init__()
        self.self_attn = AttentionBlock(embed_dims, num_heads)
        self.cross_attn = AttentionBlock(embed_dims, num_heads)
        self.ffn = FFN(embed_dims, feedforward_channels)
        self.norms = nn.ModuleList(nn.LayerNorm(embed_dims, eps=1e-5) for _ in range(3))
        self.self_posembed = PositionEncodingLearned(2, embed_dims)
        self.cross_posembed = PositionEncodingLearned(2, embed_dims)

    def forward(
        self, query: torch.Tensor, key: torch.Tensor, query_pos: torch.Tensor, key_pos: torch.Tensor
    ) -> torch.Tensor:
        # query: B x P x C, key: B x K x C, query_pos: B x P x 2, key_pos: 1 x K x 2
        qe = self.self_posembed(query_pos)
        ke = self.cross_posembed(key_pos)
        x = query + qe
        query = self.norms[0](query + self.self_attn(x, x, x))
        kv = key + ke
        query = self.norms[1](query + self.cross_attn(query + qe, kv, kv))
        return self.norms[2](query + self.ffn(query))


class SeparateHead(nn.Module):
    """mmdet3d SeparateHead with Conv1d/BN1d: per head (num_conv-1) x ConvBN then Conv1d with bias."""

    def __init__(
        self, in_channels: int, heads: Mapping[str, Sequence[int]], head_conv: int = 64, final_kernel: int = 1
    ) -> None:
        super().__init__()
        self.heads = tuple(heads)
        for name, (classes, num_conv) in heads.items():
            layers: list[nn.Module] = []
            c_in = in_channels
            for _ in range(int(num_conv) - 1):
                layers.append(ConvBN(c_in, head_conv, final_kernel, dims=1))
                c_in = head_conv
            layers.append(nn.Conv1d(c_in, int(classes), final_kernel, padding=final_kernel // 2, bias=True))
            self.add_module(name, nn.Sequential(*layers))

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        # x: B x C x P -> {name: B x out x P}
        return {name: getattr(self, name)(x) for name in self.heads}


class TransFusionHead(nn.Module):
    """Dense heatmap, proposal selection, one decoder layer, prediction heads and box decoding."""

    # Buffers (``register_buffer``), declared because ``nn.Module.__getattr__`` types them ``Tensor | Module``.
    bev_pos: torch.Tensor
    unsuppressed: torch.Tensor
    post_center_range: torch.Tensor

    def __init__(
        self,
        in_channels: int = 512,
        hidden_channel: int = 128,
        num_classes: int = 6,
        num_proposals: int = 200,
        nms_kernel_size: int = 3,
        unsuppressed_classes: Sequence[int] = (4, 5),
        num_decoder_layers: int = 1,
        num_heads: int = 8,
        ffn_channels: int = 256,
        common_heads: Mapping[str, Sequence[int]] | None = None,
        head_conv: int = 64,
        bev_size: tuple[int, int] = (160, 160),
        out_size_factor: int = 8,
        voxel_size: Sequence[float] = (0.075, 0.075),
        pc_range: Sequence[float] = (-48.0, -48.0),
        post_center_range: Sequence[float] = (-50.0, -50.0, -5.0, 50.0, 50.0, 5.0),
    ) -> None:
        super().__init__()
        self.num_classes, self.num_proposals = num_classes, num_proposals
        self.nms_kernel_size = nms_kernel_size
        self.bev_size = (int(bev_size[0]), int(bev_size[1]))
        self.out_size_factor = float(out_size_factor)
        self.voxel_size = (float(voxel_size[0]), float(voxel_size[1]))
        self.pc_range = (float(pc_range[0]), float(pc_range[1]))
        # mmcv's bias='auto' reaches nn.Conv2d as a truthy string: shared_conv has a bias.
        self.shared_conv = nn.Conv2d(in_channels, hidden_channel, 3, padding=1, bias=True)
        self.heatmap_head = nn.Sequential(
            ConvBN(hidden_channel, hidden_channel, 3, dims=2),
            nn.Conv2d(hidden_channel, num_classes, 3, padding=1, bias=True),
        )
        self.class_encoding = nn.Conv1d(num_classes, hidden_channel, 1)
        self.select = TopK(num_proposals)
        self.decoder = nn.ModuleList(
            TransFusionDecoderLayer(hidden_channel, num_heads, ffn_channels) for _ in range(num_decoder_layers)
        )
        heads = dict(DEFAULT_COMMON_HEADS if common_heads is None else common_heads)
        heads["heatmap"] = (num_classes, 2)
        self.prediction_heads = nn.ModuleList(
            SeparateHead(hidden_channel, heads, head_conv) for _ in range(num_decoder_layers)
        )
        x_size, y_size = self.bev_size
        # bev_pos[k = i*Y + j] = (i + 0.5, j + 0.5): rows are x (forward), as in the Fisheye3DOD fork.
        ii, jj = torch.meshgrid(
            torch.arange(x_size, dtype=torch.float32), torch.arange(y_size, dtype=torch.float32), indexing="ij"
        )
        bev_pos = torch.stack([ii + 0.5, jj + 0.5], dim=-1).reshape(1, x_size * y_size, 2)
        self.register_buffer("bev_pos", bev_pos, persistent=False)  # 1 x XY x 2
        keep = torch.zeros(1, num_classes, 1, 1, dtype=torch.bool)
        for c in unsuppressed_classes:
            if 0 <= c < num_classes:
                keep[0, c] = True
        self.register_buffer("unsuppressed", keep, persistent=False)  # 1 x K x 1 x 1
        self.register_buffer(
            "post_center_range", torch.tensor(list(post_center_range), dtype=torch.float32), persistent=False
        )

    def local_max_nms(self, heat: torch.Tensor) -> torch.Tensor:
        """Keep 3x3 local maxima; zero border for suppressed classes; unsuppressed classes pass through."""
        p = self.nms_kernel_size // 2
        inner = F.max_pool2d(heat, kernel_size=self.nms_kernel_size, stride=1, padding=0)
        local_max = F.pad(inner, (p, p, p, p), value=0.0)  # B x K x X x Y, border = 0
        local_max = torch.where(self.unsuppressed, heat, local_max)
        return torch.where(heat == local_max, heat, torch.zeros_like(heat))

    def forward(self, bev: torch.Tensor) -> dict[str, torch.Tensor]:
        # bev: B x Cin x X x Y
        raw = self.forward_raw(bev)
        out = self.decode(raw, raw["peak"], raw["query_labels"])
        out.update(
            {
                k: raw[k]
                for k in ("top_indices", "top_scores", "query_labels", "dense_heatmap", "rank_scores", "rank_indices")
            }
        )
        return out

    def forward_raw(self, bev: torch.Tensor) -> dict[str, torch.Tensor]:
        """Everything before decoding: what the losses need, and what ``decode`` turns into boxes.

        ``center`` (B x 2 x P, BEV cells), ``height`` (B x 1 x P, gravity centre), ``dim``
        (B x 3 x P, log l, w, h), ``rot`` (B x 2 x P, sin, cos), ``heatmap`` (B x K x P, class
        logits), ``dense_heatmap`` (B x K x X x Y logits), ``query_labels`` / ``top_indices``
        (B x P), ``peak`` (B x K x P, suppressed heatmap at the proposal cells).
        """
        feat = self.shared_conv(bev)  # B x C x X x Y
        b, c = feat.shape[0], feat.shape[1]
        xy = self.bev_size[0] * self.bev_size[1]
        feat_flat = feat.reshape(b, c, xy)  # B x C x XY
        dense_heatmap = self.heatmap_head(feat)  # B x K x X x Y (logits)
        rank_scores = self.select.dense(torch.sigmoid(dense_heatmap).reshape(b, self.num_classes * xy))  # B x K*XY
        heat = self.local_max_nms(rank_scores.reshape_as(dense_heatmap)).reshape(b, self.num_classes, xy)
        top_score, top_idx = self.select(heat.reshape(b, self.num_classes * xy))  # B x P
        cls = torch.div(top_idx, xy, rounding_mode="floor")  # B x P (int64)
        cell = top_idx - cls * xy
        query = feat_flat.gather(2, cell.unsqueeze(1).expand(b, c, self.num_proposals))  # B x C x P
        # class_encoding(one_hot(cls)) == W[:, cls] + b exactly (one non-zero term per output).
        w_cls = self.class_encoding.weight[:, :, 0].t()  # K x C
        bias = self.class_encoding.bias
        assert bias is not None  # nn.Conv1d's default bias=True
        enc = F.embedding(cls, w_cls) + bias  # B x P x C
        query = (query + enc.transpose(1, 2)).transpose(1, 2)  # B x P x C
        query_pos = self.bev_pos[0][cell]  # B x P x 2
        key = feat_flat.transpose(1, 2)  # B x XY x C
        res: dict[str, torch.Tensor] = {}
        for layer, pred_head in zip(self.decoder, self.prediction_heads):
            query = layer(query, key, query_pos, self.bev_pos)
            res = pred_head(query.transpose(1, 2))
            res["center"] = res["center"] + query_pos.transpose(1, 2)
            query_pos = res["center"].detach().transpose(1, 2)
        peak = heat.gather(2, cell.unsqueeze(1).expand(b, self.num_classes, self.num_proposals))  # B x K x P
        res.update(
            peak=peak,
            top_indices=top_idx,
            top_scores=top_score,
            query_labels=cls,
            dense_heatmap=dense_heatmap,
            rank_scores=rank_scores,
            rank_indices=top_idx,
        )
        return res

    def decode(self, res: Mapping[str, torch.Tensor], peak: torch.Tensor, cls: torch.Tensor) -> dict[str, torch.Tensor]:
        """Boxes in the lidar frame: (x, y, z_bottom, l, w, h, yaw), plus scores, labels, valid, rot."""
        k = self.num_classes
        own = torch.arange(k, device=cls.device).reshape(1, k, 1) == cls.unsqueeze(1)  # B x K x P
        prod = torch.sigmoid(res["heatmap"]) * peak
        score_all = torch.where(own, prod, torch.zeros_like(prod))
        scores, labels = torch.max(score_all, dim=1)  # B x P; first index on ties
        center = res["center"]
        cx = center[:, 0] * self.out_size_factor * self.voxel_size[0] + self.pc_range[0]
        cy = center[:, 1] * self.out_size_factor * self.voxel_size[1] + self.pc_range[1]
        dims = torch.exp(res["dim"])  # B x 3 x P  (l, w, h)
        z_bottom = res["height"][:, 0] - dims[:, 2] * 0.5
        rot = res["rot"]  # B x 2 x P  (sin, cos)
        yaw = torch.atan2(rot[:, 0], rot[:, 1])
        boxes = torch.stack([cx, cy, z_bottom, dims[:, 0], dims[:, 1], dims[:, 2], yaw], dim=-1)  # B x P x 7
        pcr = self.post_center_range
        ctr = boxes[..., :3]
        valid = ((ctr >= pcr[:3]).all(dim=-1)) & ((ctr <= pcr[3:]).all(dim=-1))
        return {"boxes": boxes, "scores": scores, "labels": labels, "valid": valid, "rot": rot.transpose(1, 2)}
