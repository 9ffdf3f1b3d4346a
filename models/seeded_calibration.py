"""Making seeded random weights behave like trained ones: the calibrations behind synthetic checkpoints.

`init_weights` gives a model fan-in scaled weights and small biases; `calibrate` (per model family)
then collects every BatchNorm's running statistics on seeded synthetic frames (`batchnorm_statistics`,
`synthetic_images`), tempers the attention logits (`temper_attention`) and maps the heads' last
layers onto a trained head's output range, so activations stay O(1) at inference.
[`make_checkpoint`][fisheye_infer.models.seeded_checkpoint.make_checkpoint] writes the result in
the official format.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Callable, Iterator
from typing import Any

import torch
import torch.nn.functional as F
from torch import nn

from .fisheye_bevdet import FisheyeBEVDet
from .fisheye_petr import FisheyePETR

__all__ = [
    "init_weights",
    "batchnorm_statistics",
    "temper_attention",
    "synthetic_images",
    "calibrate",
    "calibrate_bevdet",
    "calibrate_petr",
    "CALIBRATION_FRAMES",
    "CALIBRATION_MAX_SIDE",
    "HEATMAP_PRIOR_LOGIT",
    "CLS_PRIOR_LOGIT",
    "BOX_HEAD_TARGETS",
]

_BN = (nn.BatchNorm1d, nn.BatchNorm2d)


def init_weights(model: nn.Module, seed: int) -> None:
    """Kaiming-like weights (std sqrt(2 / fan_in)), small biases, BN/LN affine near identity.

    Parameters that are not covered by a known module type (e.g. packed attention projections)
    get std sqrt(1 / fan_in) over their last dimension.
    """
    gen = torch.Generator().manual_seed(int(seed))

    def normal(t: torch.Tensor, std: float, mean: float = 0.0) -> None:
        with torch.no_grad():
            t.copy_(torch.randn(t.shape, generator=gen) * std + mean)

    done: set[int] = set()
    for module in model.modules():
        if isinstance(module, (nn.Conv1d, nn.Conv2d)):
            fan_in = module.in_channels // module.groups * math.prod(module.kernel_size)
            normal(module.weight, math.sqrt(2.0 / fan_in))
        elif isinstance(module, nn.ConvTranspose2d):
            # each output pixel of a k = s transposed conv sees exactly in_channels inputs
            taps = math.prod(module.kernel_size) / math.prod(module.stride)
            normal(module.weight, math.sqrt(2.0 / (module.in_channels * max(taps, 1.0))))
        elif isinstance(module, nn.Linear):
            normal(module.weight, math.sqrt(1.0 / module.in_features))
        elif isinstance(module, (*_BN, nn.LayerNorm)):
            normal(module.weight, 0.1, 1.0)
            if module.bias is not None:
                normal(module.bias, 0.1)
            if isinstance(module, _BN):
                module.reset_running_stats()
        else:
            continue
        bias: torch.Tensor | None = module.bias
        done.update({id(module.weight)} | ({id(bias)} if bias is not None else set()))
        if bias is not None and not isinstance(module, (*_BN, nn.LayerNorm)):
            normal(bias, 0.02)
    for _, param in model.named_parameters():
        if id(param) in done:
            continue
        if param.dim() >= 2:
            normal(param, math.sqrt(1.0 / param.shape[-1]))
        else:
            normal(param, 0.02)


@contextlib.contextmanager
def batchnorm_statistics(model: nn.Module) -> Iterator[None]:
    """Inside the block BN layers normalise with batch statistics and accumulate a cumulative average
    of them (momentum=None) into fresh running statistics; everything else stays in eval mode."""
    bns = [m for m in model.modules() if isinstance(m, _BN)]
    saved = [(m.momentum, m.training) for m in bns]
    model.eval()
    for m in bns:
        m.reset_running_stats()
        m.momentum = None
        m.train()
    try:
        with torch.no_grad():
            yield
    finally:
        for m, (momentum, _) in zip(bns, saved):
            m.momentum = momentum
            m.eval()
        model.eval()


@torch.no_grad()
def temper_attention(model: nn.Module, run: Callable[[], object], target_std: float = 1.0) -> None:
    """Scale each attention's query projection so its logits have standard deviation ``target_std``.

    Random projections of strongly correlated features (the same feature plus a position
    embedding) give attention logits in the tens: softmax then turns float32 rounding into
    errors of 1e-3 relative at the output, where a trained model sees about 1e-5. ``run``
    performs one forward pass; attention modules are those with a packed ``in_proj_weight``.
    """
    stds: dict[nn.Module, float] = {}

    def measure(module: nn.Module, args: tuple[torch.Tensor, ...], _kwargs: dict[str, Any] | None = None) -> None:
        q, k = args[0], args[1]
        weight, bias = _in_projection(module)
        c = weight.shape[1]
        heads = int(getattr(module, "num_heads", 1))
        w_q, w_k, _ = weight.split(c, dim=0)
        b_q, b_k, _ = bias.split(c, dim=0)
        qh = F.linear(q, w_q, b_q).reshape(*q.shape[:-1], heads, c // heads)
        kh = F.linear(k, w_k, b_k).reshape(*k.shape[:-1], heads, c // heads)
        logits = torch.einsum("...qhd,...khd->...hqk", qh, kh) / math.sqrt(c // heads)
        stds[module] = float(logits.std())

    modules = [m for m in model.modules() if hasattr(m, "in_proj_weight") and hasattr(m, "in_proj_bias")]
    handles = [m.register_forward_pre_hook(measure) for m in modules]
    try:
        run()
    finally:
        for h in handles:
            h.remove()
    for module, std in stds.items():
        if std > target_std:
            weight, bias = _in_projection(module)
            c = weight.shape[1]
            weight[:c].mul_(target_std / std)
            bias[:c].mul_(target_std / std)


def _in_projection(module: nn.Module) -> tuple[torch.Tensor, torch.Tensor]:
    """A packed attention's (in_proj_weight, in_proj_bias): the q, k and v projections stacked along dim 0."""
    weight, bias = module.in_proj_weight, module.in_proj_bias
    if not (isinstance(weight, torch.Tensor) and isinstance(bias, torch.Tensor)):
        raise TypeError(f"{type(module).__name__}: in_proj_weight and in_proj_bias must be tensors")
    return weight, bias


def synthetic_images(seed: int, batch: int, cameras: int, height: int, width: int) -> torch.Tensor:
    """uint8 B x N x H x W x 3 frames: smooth random blobs plus fine texture, deterministic in ``seed``."""
    gen = torch.Generator().manual_seed(int(seed) + 7919)
    coarse = torch.rand(batch * cameras, 3, max(height // 32, 2), max(width // 32, 2), generator=gen)
    mid = torch.rand(batch * cameras, 3, max(height // 8, 2), max(width // 8, 2), generator=gen)
    fine = torch.rand(batch * cameras, 3, height, width, generator=gen)
    up = lambda t: nn.functional.interpolate(t, size=(height, width), mode="bilinear", align_corners=False)  # noqa: E731
    img = 0.55 * up(coarse) + 0.3 * up(mid) + 0.15 * fine
    img = (img * 255.0).round().clamp(0, 255).to(torch.uint8)
    return img.permute(0, 2, 3, 1).reshape(batch, cameras, height, width, 3).contiguous()


# -- making seeded random weights behave like trained ones ------------------------------------------

CALIBRATION_FRAMES = 2
#: Backbone statistics barely depend on image size, and both heads sample P3 through normalised
#: grids, so calibration runs on frames of at most this side (the networks are fully convolutional
#: up to the grid).
CALIBRATION_MAX_SIDE = 320
HEATMAP_PRIOR_LOGIT = -2.19
CLS_PRIOR_LOGIT = -4.595  # official cls bias init, bias_init_with_prob(0.01)


def calibrate(model: nn.Module, seed: int) -> None:
    """The calibration of ``model``'s family (FisheyeBEVDet or FisheyePETR, and their baselines); other
    models keep their weights."""
    if isinstance(model, FisheyeBEVDet):
        calibrate_bevdet(model, seed)
    elif isinstance(model, FisheyePETR):
        calibrate_petr(model, seed)


def calibrate_bevdet(model: FisheyeBEVDet, seed: int) -> None:
    """Collect BatchNorm statistics on seeded synthetic frames (image side capped for speed).

    The whole network is fully convolutional up to the angular grid, so smaller frames still
    exercise the full BEV grid and head with realistic statistics.
    """
    cfg = model.config
    scale = min(1.0, CALIBRATION_MAX_SIDE / max(cfg.image.height, cfg.image.width))
    h = max(32, int(round(cfg.image.height * scale / 32)) * 32)
    w = max(32, int(round(cfg.image.width * scale / 32)) * 32)
    n = len(model.camera_names)
    frames = [synthetic_images(seed * 1000 + i, 1, n, h, w) for i in range(CALIBRATION_FRAMES)]
    with batchnorm_statistics(model):
        for frame in frames:
            model.predict(frame)
    temper_attention(model, lambda: model.predict(frames[0]))
    _shape_box_heads(model, frames[0])
    # Heatmap logits: affine-map so the median cell sits at the official prior (-2.19, p = 0.1) and
    # the largest at about +0.8 (p = 0.69): peaks stay far from sigmoid saturation, where float32
    # would round neighbouring scores to the same value and create ties at the top-k boundary.
    with torch.no_grad():
        logits = model.predict(frames[0])["dense_heatmap"]
        median, top = logits.median(), logits.max()
        scale = 3.0 / max(float(top - median), 1e-3)
        final = model.bbox_head.heatmap_head[1]
        assert isinstance(final, nn.Conv2d) and final.bias is not None
        final.weight.mul_(scale)
        final.bias.mul_(scale).add_(HEATMAP_PRIOR_LOGIT - scale * float(median))


#: Target (mean, std) of the raw regression outputs of a trained head: centre offsets in cells,
#: gravity-centre height (m), log box sizes (l, w, h of a car-sized box), and sin/cos of yaw with
#: a norm near 1 (atan2 of a near-zero vector turns float32 rounding into large yaw errors; a
#: trained head predicts unit vectors, a random one does not unless told).
BOX_HEAD_TARGETS = {
    "center": ((0.0, 0.0), 0.3),
    "height": ((-0.8,), 0.4),
    "dim": ((1.4, 0.65, 0.45), 0.25),
    "rot": ((0.7, 0.7), 0.1),
}


@torch.no_grad()
def _shape_box_heads(model: FisheyeBEVDet, frame: torch.Tensor) -> None:
    """Affine-map each regression head's last layer so its outputs have a trained head's range.

    Random heads predict log-sizes of +-4 (boxes of 50 m): exp() then multiplies float32
    rounding by the box size, which a trained model never does.
    """
    head = model.bbox_head.prediction_heads[0]
    outputs: dict[str, torch.Tensor] = {}
    hooks = [
        getattr(head, name)[-1].register_forward_hook(lambda m, i, o, name=name: outputs.__setitem__(name, o))
        for name in BOX_HEAD_TARGETS
    ]
    try:
        model.predict(frame)
    finally:
        for h in hooks:
            h.remove()
    for name, (means, std) in BOX_HEAD_TARGETS.items():
        final = getattr(head, name)[-1]
        out = outputs[name]  # B x C x P
        mu, sigma = out.mean(dim=(0, 2)), out.std(dim=(0, 2)).clamp(min=1e-6)
        gain = std / sigma
        final.weight.mul_(gain[:, None, None])
        final.bias.copy_((final.bias - mu) * gain + torch.tensor(means, dtype=final.bias.dtype))


def calibrate_petr(model: FisheyePETR, seed: int) -> None:
    """Make seeded random weights behave like a trained model's, for synthetic checkpoints.

    Reference points get the official init U(0, 1) (so boxes spread over the range instead of
    collapsing to its corners), BatchNorm statistics are collected on synthetic frames, and the
    last cls layer is affine-mapped so the median logit sits at the official prior and the top
    at prior + 3 (no sigmoid saturation, hence no score ties at the top-k boundary). The cls
    branch reads post-normed decoder features, so unit-variance features stand in for them.
    """
    cfg = model.config
    head = model.pts_bbox_head
    gen = torch.Generator().manual_seed(int(seed) + 101)
    with torch.no_grad():
        head.reference_points.weight.copy_(torch.rand(head.reference_points.weight.shape, generator=gen))
        head.query_pos.copy_(head.query_positions())
    image_size = (cfg.image.height, cfg.image.width)
    scale = min(1.0, CALIBRATION_MAX_SIDE / max(image_size))
    h, w = (max(32, int(round(s * scale / 32)) * 32) for s in image_size)
    frames = [synthetic_images(int(seed) * 1000 + i, 1, cfg.num_cameras, h, w) for i in range(CALIBRATION_FRAMES)]
    with batchnorm_statistics(model):
        for frame in frames:
            model.image_features(frame)
    temper_attention(model, lambda: model.scene_features(model.image_features(frames[0])))
    with torch.no_grad():
        feats = head.transformer.decoder.post_norm(torch.randn(cfg.head.num_query, cfg.head.embed_dims, generator=gen))
        cls, _ = head.predict(feats)
        median, top = cls.median(), cls.max()
        gain = 3.0 / max(float(top - median), 1e-3)
        branch = head.cls_branches[-1]
        assert isinstance(branch, nn.Sequential)
        final = branch[-1]
        assert isinstance(final, nn.Linear)
        final.weight.mul_(gain)
        final.bias.mul_(gain).add_(CLS_PRIOR_LOGIT - gain * float(median))
