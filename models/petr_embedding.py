"""PETR's weight-side embeddings in torch: clamped inverse sigmoid and the query sine encoding.

They act on learned tensors (the reference points), so they live with the model; the key-side
sine encoding depends only on the calibration mask and comes from
[`sine_position_encoding`][fisheye_infer.geometry.petr.sine_position_encoding]. The official float32 op order of
``pos2posemb3d`` is kept:

* frequencies t_k = temperature ** (2 * floor(k / 2) / num_feats), k = 0 .. num_feats - 1;
* E(a)[k] = sin(a / t_k) for even k and cos(a / t_k) for odd k (interleaved sin/cos pairs);
* ``pos2posemb3d``: 2*pi * reference point, concatenated in the order (y, x, z).
"""

from __future__ import annotations

import math

import torch

__all__ = ["inverse_sigmoid", "sine_frequencies", "interleave_sin_cos", "pos2posemb3d", "INVERSE_SIGMOID_EPS"]

INVERSE_SIGMOID_EPS = 1e-5


def inverse_sigmoid(x: torch.Tensor, eps: float = INVERSE_SIGMOID_EPS) -> torch.Tensor:
    """mmdet's inverse_sigmoid: clamp to [0, 1], then log(max(x, eps) / max(1 - x, eps)).

    The result saturates at +-log(1/eps) = +-11.5129 for eps = 1e-5.
    """
    x = x.clamp(min=0.0, max=1.0)
    return torch.log(x.clamp(min=eps) / (1.0 - x).clamp(min=eps))


def sine_frequencies(
    num_feats: int = 128, temperature: float = 10000.0, device: torch.device | None = None
) -> torch.Tensor:
    """(num_feats,) float32 divisors t_k, computed like the official code (float32 pow)."""
    dim_t = torch.arange(num_feats, dtype=torch.float32, device=device)
    return temperature ** (2 * torch.div(dim_t, 2, rounding_mode="floor") / num_feats)


def interleave_sin_cos(a: torch.Tensor, dim_t: torch.Tensor) -> torch.Tensor:
    """(...,) -> (..., F): sin of the even and cos of the odd frequencies, interleaved."""
    p = a.unsqueeze(-1) / dim_t  # ... x F
    return torch.stack((p[..., 0::2].sin(), p[..., 1::2].cos()), dim=-1).flatten(-2)


def pos2posemb3d(pos: torch.Tensor, num_feats: int = 128, temperature: float = 10000.0) -> torch.Tensor:
    """Reference points (Q, 3) -> (Q, 3 * num_feats) query features, order (y, x, z).

    The points are used raw (the official head does not sigmoid them), so values outside
    [0, 1] are encoded as they are.
    """
    dim_t = sine_frequencies(num_feats, temperature, pos.device)
    pos = pos * (2 * math.pi)
    px = interleave_sin_cos(pos[..., 0], dim_t)
    py = interleave_sin_cos(pos[..., 1], dim_t)
    pz = interleave_sin_cos(pos[..., 2], dim_t)
    return torch.cat((py, px, pz), dim=-1)
