"""The PETR transformer decoder with mmcv's module names and written for a clean ONNX graph.

Why not ``nn.MultiheadAttention``: with a boolean key padding mask it exports as Where/-inf
chains, and its fast path differs between train/eval and torch versions. Here attention is
explicit MatMul -> Softmax -> MatMul, with the key mask given as an additive bias (0 for kept
keys, ``MASK_BIAS`` for ignored ones) that rides in the Q.K^T product as one more dimension
(see ``MultiheadAttention``). The parameters keep the exact layout of
``nn.MultiheadAttention`` (``in_proj_weight`` rows 0:C, C:2C, 2C:3C are Q, K, V; ``out_proj``),
so official checkpoints load by key:

    transformer.decoder.layers.{i}.attentions.{0,1}.attn.{in_proj_weight,in_proj_bias,out_proj.*}
    transformer.decoder.layers.{i}.ffns.0.layers.{0.0,1}.*      transformer.decoder.layers.{i}.norms.{0,1,2}.*
    transformer.decoder.post_norm.*

Tensors are batch-first here (B x L x C); the official code is sequence-first, which changes no
arithmetic.
"""

from __future__ import annotations

import math
from typing import ClassVar, cast

import torch
import torch.nn.functional as F
from torch import nn

__all__ = [
    "MASK_BIAS",
    "QUERY_CHUNK",
    "MultiheadAttention",
    "AttentionBlock",
    "FFN",
    "PETRDecoderLayer",
    "PETRTransformerDecoder",
    "PETRTransformer",
    "key_padding_bias",
]

#: Additive logit for ignored keys. -1e30 gives exactly 0 after exp in float32 (like -inf), but a
#: row whose keys are all ignored stays finite (uniform attention) instead of turning into NaN.
MASK_BIAS = -1e30
#: Queries per chunk of the inference graph's attention (``MultiheadAttention.forward``).
QUERY_CHUNK = 100


def key_padding_bias(mask: torch.Tensor) -> torch.Tensor:
    """Bool key padding mask (True = ignore), any shape -> float bias of the same shape."""
    return torch.where(
        mask, torch.full_like(mask, MASK_BIAS, dtype=torch.float32), torch.zeros_like(mask, dtype=torch.float32)
    )


class MultiheadAttention(nn.Module):
    """Scaled dot-product attention with ``nn.MultiheadAttention``'s parameters and arithmetic.

    As in torch >= 2.0 the queries are multiplied by sqrt(1/head_dim) before Q.K^T.
    """

    #: Training mode runs PyTorch's fused kernel (see ``forward``); False trains through the explicit
    #: graph, which ``benchmarks/train_step.py``'s ``*-explicit-*`` cases time against.
    fused_in_training: ClassVar[bool] = True

    def __init__(self, embed_dims: int, num_heads: int) -> None:
        super().__init__()
        self.embed_dims = embed_dims
        self.num_heads = num_heads
        self.head_dims = embed_dims // num_heads
        self.in_proj_weight = nn.Parameter(torch.empty(3 * embed_dims, embed_dims))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * embed_dims))
        self.out_proj = nn.Linear(embed_dims, embed_dims)
        nn.init.xavier_uniform_(self.in_proj_weight)
        nn.init.zeros_(self.out_proj.bias)

    def _heads(self, x: torch.Tensor) -> torch.Tensor:
        # B x L x C -> B x h x L x d
        b, length, _ = x.shape
        return x.reshape(b, length, self.num_heads, self.head_dims).transpose(1, 2)

    def forward(
        self, query: torch.Tensor, key: torch.Tensor, value: torch.Tensor, key_bias: torch.Tensor | None = None
    ) -> torch.Tensor:
        """query B x Q x C, key/value B x K x C, key_bias B|1 x K (additive, per key) -> B x Q x C.

        The key bias enters the logits through the product itself: q gets a last coordinate 1
        and k the key's bias, so Q.K^T already holds q.k + bias. Adding a B x h x 1 x K bias to
        the B x h x Q x K logits instead is one more pass over the largest tensor of the graph;
        on FisheyePETR (900 queries, 10000 keys, 8 heads) ONNX Runtime spent as long on that Add
        as on the softmax. The sums are the same up to float32 rounding order.

        The queries go through in chunks of ``QUERY_CHUNK``: a chunk's logits (B x h x 100 x K) stay in the
        cache from their product through the softmax to the second product, where the whole B x h x Q x K would
        travel through memory three times (the compact FisheyePETR: 4 heads, 900 queries, 1600 keys, 23 MB a layer).
        Each query's row is the same computation either way.

        In training mode the same attention is PyTorch's fused ``scaled_dot_product_attention``
        (the bias as its additive mask), whose forward and backward never hold the B x h x Q x K
        logits and probabilities: on one CPU thread a frozen-backbone training step of the compact
        FisheyePETR with the official 900 queries takes about 0.7 of the explicit graph's time (with
        300, the same; ``benchmarks/train_step.py``, its ``petr-*`` cases).
        The explicit graph is for inference and export.
        """
        c = self.embed_dims
        w, b = self.in_proj_weight, self.in_proj_bias
        q = self._heads(F.linear(query, w[:c], b[:c]))
        k = self._heads(F.linear(key, w[c : 2 * c], b[c : 2 * c]))
        v = self._heads(F.linear(value, w[2 * c :], b[2 * c :]))
        if self.training and self.fused_in_training:
            mask = None if key_bias is None else key_bias[:, None, None, :]
            return self._merged(F.scaled_dot_product_attention(q, k, v, attn_mask=mask))
        q = q * math.sqrt(1.0 / self.head_dims)
        if key_bias is not None:
            q = torch.cat((q, torch.ones_like(q[..., :1])), dim=-1)
            k = torch.cat((k, key_bias[:, None, :, None].expand(k.shape[0], k.shape[1], -1, 1)), dim=-1)
        kt = k.transpose(-2, -1)
        rows = [torch.matmul(torch.softmax(torch.matmul(part, kt), dim=-1), v) for part in q.split(QUERY_CHUNK, dim=2)]
        return self._merged(torch.cat(rows, dim=2) if len(rows) > 1 else rows[0])  # B x h x Q x d

    def _merged(self, heads: torch.Tensor) -> torch.Tensor:
        # B x h x Q x d -> B x Q x C, through out_proj
        bsz, _, n_q, _ = heads.shape
        return self.out_proj(heads.transpose(1, 2).reshape(bsz, n_q, self.embed_dims))


class AttentionBlock(nn.Module):
    """mmcv ``MultiheadAttention`` wrapper: positions are added to query and key, never to value,
    and the residual is the input query (dropouts are inactive at inference)."""

    def __init__(self, embed_dims: int, num_heads: int) -> None:
        super().__init__()
        self.attn = MultiheadAttention(embed_dims, num_heads)

    def forward(
        self,
        query: torch.Tensor,
        key: torch.Tensor,
        value: torch.Tensor,
        query_pos: torch.Tensor,
        key_pos: torch.Tensor,
        key_bias: torch.Tensor | None = None,
    ) -> torch.Tensor:
        return query + self.attn(query + query_pos, key + key_pos, value, key_bias)


class FFN(nn.Module):
    """mmcv FFN (2 fcs, ReLU, identity added): keys ``layers.0.0`` and ``layers.1``."""

    def __init__(self, embed_dims: int, ffn_dims: int) -> None:
        super().__init__()
        self.layers = nn.Sequential(
            nn.Sequential(nn.Linear(embed_dims, ffn_dims), nn.ReLU()),
            nn.Linear(ffn_dims, embed_dims),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return x + self.layers(x)


class PETRDecoderLayer(nn.Module):
    """Post-norm layer: self_attn, norm, cross_attn, norm, ffn, norm."""

    def __init__(self, embed_dims: int = 256, num_heads: int = 8, ffn_dims: int = 2048) -> None:
        super().__init__()
        self.attentions = nn.ModuleList([AttentionBlock(embed_dims, num_heads), AttentionBlock(embed_dims, num_heads)])
        self.ffns = nn.ModuleList([FFN(embed_dims, ffn_dims)])
        self.norms = nn.ModuleList([nn.LayerNorm(embed_dims) for _ in range(3)])

    def forward(
        self,
        target: torch.Tensor,
        memory: torch.Tensor,
        query_pos: torch.Tensor,
        key_pos: torch.Tensor,
        key_bias: torch.Tensor | None,
    ) -> torch.Tensor:
        # target B x Q x C; memory B x K x C; query_pos 1|B x Q x C; key_pos 1|B x K x C
        return self.attend_memory(self.attend_self(target, query_pos), memory, query_pos, key_pos, key_bias)

    def attend_self(self, target: torch.Tensor, query_pos: torch.Tensor) -> torch.Tensor:
        """Self-attention (q = k = target + query_pos, v = target), then the first norm."""
        return self.norms[0](self.attentions[0](target, target, target, query_pos, query_pos))

    def attend_memory(
        self,
        t: torch.Tensor,
        memory: torch.Tensor,
        query_pos: torch.Tensor,
        key_pos: torch.Tensor,
        key_bias: torch.Tensor | None,
    ) -> torch.Tensor:
        """Cross-attention (q = t + query_pos, k = memory + key_pos, v = memory), norm, FFN, norm."""
        t = self.norms[1](self.attentions[1](t, memory, memory, query_pos, key_pos, key_bias))
        return self.norms[2](self.ffns[0](t))


class PETRTransformerDecoder(nn.Module):
    """Six post-norm layers; ``post_norm`` is applied only to the outputs that are returned.

    The un-normalised output of layer l is the input of layer l+1 (official
    ``PETRTransformerDecoder``), so ``post_norm`` never enters the recurrence.
    """

    def __init__(self, num_layers: int = 6, embed_dims: int = 256, num_heads: int = 8, ffn_dims: int = 2048) -> None:
        super().__init__()
        self.layers = nn.ModuleList(PETRDecoderLayer(embed_dims, num_heads, ffn_dims) for _ in range(num_layers))
        self.post_norm = nn.LayerNorm(embed_dims)

    def forward(
        self,
        target: torch.Tensor,
        memory: torch.Tensor,
        query_pos: torch.Tensor,
        key_pos: torch.Tensor,
        key_bias: torch.Tensor | None,
        return_intermediate: bool = False,
        self_attended: bool = False,
    ) -> torch.Tensor:
        """-> B x Q x C (last layer, post-normed) or L x B x Q x C with ``return_intermediate``.

        ``self_attended``: ``target`` is the first layer's self-attention output (``attend_self``), and the first
        layer starts at its cross-attention.
        """
        outs = []
        t = target
        for i, layer in enumerate(cast("list[PETRDecoderLayer]", self.layers)):
            if i == 0 and self_attended:
                t = layer.attend_memory(t, memory, query_pos, key_pos, key_bias)
            else:
                t = layer(t, memory, query_pos, key_pos, key_bias)
            if return_intermediate:
                outs.append(self.post_norm(t))
        if return_intermediate:
            return torch.stack(outs)
        return self.post_norm(t)


class PETRTransformer(nn.Module):
    """Flattens the camera features into keys (order n, h, w) and runs the decoder from zero targets.

    The first layer's self-attention of the zero targets reads only weights and the query positions: one (1, Q, C)
    tensor for every frame. ``cache_first_self_attention`` keeps it in a non-persistent buffer, which an inference
    with the cached positions reads (``forward(cached=True)``), so an exported graph holds it as a constant and no
    runtime computes it per frame (on the compact FisheyePETR, 9 of the decoder's 108 softmaxes over 900 x 900 or
    900 x 1600 logits). Each frame's numbers are those of the decoder run from B x Q x C zeros.
    """

    # A buffer (``register_buffer``), declared because ``nn.Module.__getattr__`` types it ``Tensor | Module``.
    first_self_attention: torch.Tensor

    def __init__(self, num_layers: int = 6, embed_dims: int = 256, num_heads: int = 8, ffn_dims: int = 2048) -> None:
        super().__init__()
        self.decoder = PETRTransformerDecoder(num_layers, embed_dims, num_heads, ffn_dims)
        self.register_buffer("first_self_attention", torch.zeros(0), persistent=False)

    def self_attention_of_zero_targets(self, query_pos: torch.Tensor) -> torch.Tensor:
        """(1, Q, C): the first layer's self-attention of zero targets at ``query_pos`` (Q, C), normed."""
        zeros = query_pos.new_zeros((1, *query_pos.shape))
        first = cast(PETRDecoderLayer, self.decoder.layers[0])
        return first.attend_self(zeros, query_pos.unsqueeze(0))

    @torch.no_grad()
    def cache_first_self_attention(self, query_pos: torch.Tensor) -> None:
        """Keep ``self_attention_of_zero_targets(query_pos)`` for ``forward(cached=True)``; call it again whenever the
        weights or the query positions change."""
        self.first_self_attention = self.self_attention_of_zero_targets(query_pos)

    def forward(
        self,
        memory: torch.Tensor,
        query_pos: torch.Tensor,
        key_pos: torch.Tensor,
        key_bias: torch.Tensor | None,
        return_intermediate: bool = False,
        cached: bool = False,
    ) -> torch.Tensor:
        """memory B x K x C, query_pos Q x C, key_pos 1|B x K x C, key_bias B|1 x K (additive).

        ``cached``: the first self-attention is the buffer ``cache_first_self_attention`` filled for these
        ``query_pos``. Outside training the (1, Q, C) targets broadcast over the batch in the first cross-attention's
        products and residual; in training they are expanded to the batch for PyTorch's fused attention.
        """
        first = self.first_self_attention if cached else self.self_attention_of_zero_targets(query_pos)
        if self.training:
            first = first.expand(memory.shape[0], -1, -1)
        return self.decoder(first, memory, query_pos.unsqueeze(0), key_pos, key_bias, return_intermediate, True)
