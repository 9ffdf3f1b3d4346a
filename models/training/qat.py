"""Quantization-aware training: the int8 file's rounding simulated in the layers it quantizes.

    fq = FakeQuant(model, keep_float=INT8_FLOAT)   # every Conv/ConvTranspose/Linear not kept float
    fq.enabled = True                               # this forward rounds as the int8 file will
    ...
    fq.remove()                                     # the model's own forwards again

Why: post-training int8 moves a vehicle's heatmap peak to the neighbouring 1.2 m cell often
enough that the int8 file keeps a quarter fewer of the vehicles' top-50 boxes than the fp32 file
(README, int8). A model that sees the same rounding while it learns can place its weights where
the rounding matters less. On the shipped model it changed the int8 figures by no more than two
fine-tuning runs differ (its model card has the comparison).

What is simulated, in the layers ``export.quantize`` makes int8 (``network`` scope, the
architecture's ``int8_float`` modules left float):

- the weights, symmetric, on the ``WEIGHT_QMAX[WEIGHT_BITS]`` grid (7 bits: [-64, 64]), one scale
  per output channel; per output channel and kernel position for a ConvTranspose2d with kernel =
  stride, which the export turns into a 1x1 Conv to ``out x k x k`` channels and a DepthToSpace.
  Weights are rounded before BatchNorm is folded into them: per-channel symmetric rounding
  commutes with the per-channel scale the fold applies, so the grid is the file's;
- the layer's input, per tensor as U8 with a zero point, over ONNX Runtime's percentile range (the
  ``CALIBRATION_PERCENTILE`` of the magnitudes, clipped to the minimum and maximum), followed as
  a running mean over the training batches.

The file also rounds each int8 layer's output (after the folded BatchNorm); where that output
feeds another int8 layer, this is its input's rounding, but the outputs that go on in float (the
depth logits into the softmax, the image features into the warp, the head's first heatmap
convolution) are not rounded here. Gradients pass the rounding straight through.

Nothing is added to the model: its state dict, and so its checkpoints, stay those of the plain
model; the simulation lives in this object (``ranges``, saved with the optimiser by the training
loop) and in the layers' replaced ``forward``.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence

import torch
import torch.nn.functional as F
from torch import nn

from fisheye_infer.precision import CALIBRATION_PERCENTILE, WEIGHT_BITS, WEIGHT_QMAX, under_module

__all__ = ["FakeQuant", "fake_quant_weight", "fake_quant_activation", "percentile_range"]

#: Values a batch's percentile is estimated from (every n-th: ``torch.quantile`` takes at most 2^24,
#: and a fixed stride keeps a run a function of its options, as a random subset would not).
RANGE_SAMPLES = 1 << 16
#: Weight of each new batch in the running range.
RANGE_MOMENTUM = 0.05


def fake_quant_weight(weight: torch.Tensor, axis: int, qmax: int) -> torch.Tensor:
    """``weight`` rounded per slice along ``axis`` (the output channels) to the symmetric grid [-qmax, qmax]."""
    dims = [d for d in range(weight.dim()) if d != axis]
    scale = (weight.detach().abs().amax(dim=dims) / qmax).clamp_min(1e-12).float()
    zero = torch.zeros_like(scale, dtype=torch.int32)
    return torch.fake_quantize_per_channel_affine(weight, scale, zero, axis, -qmax, qmax)


def fake_quant_activation(x: torch.Tensor, low: torch.Tensor, high: torch.Tensor) -> torch.Tensor:
    """``x`` rounded to U8 over [low, high] (widened to hold 0, which U8 with a zero point represents exactly)."""
    low, high = low.clamp(max=0.0), high.clamp(min=0.0)
    scale = ((high - low) / 255).clamp_min(1e-8).reshape(1).float()
    zero = torch.round(-low / scale).clamp(0, 255).to(torch.int32).reshape(1)
    return torch.fake_quantize_per_tensor_affine(x, scale, zero, 0, 255)


def percentile_range(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """ONNX Runtime's percentile calibration of one tensor: +-T, T the ``CALIBRATION_PERCENTILE`` of
    ``|x|`` (estimated on every n-th value), clipped to ``x``'s minimum and maximum."""
    flat = x.detach().reshape(-1).float()
    sample = flat[:: max(1, flat.numel() // RANGE_SAMPLES)]
    t = torch.quantile(sample.abs(), CALIBRATION_PERCENTILE / 100)
    return torch.maximum(flat.min(), -t), torch.minimum(flat.max(), t)


def _conv(m: nn.Conv2d, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return m._conv_forward(x, w, m.bias)


def _rewritten_as_depth_to_space(m: nn.ConvTranspose2d) -> bool:
    """Whether the export turns ``m`` into a 1x1 Conv + DepthToSpace (``int8_rewrites.upsample_as_depth_to_space``)."""
    return (
        m.kernel_size == m.stride
        and m.groups == 1
        and m.padding == (0, 0)
        and m.dilation == (1, 1)
        and m.output_padding == (0, 0)
    )


def _conv_transpose(m: nn.ConvTranspose2d, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    if m.padding_mode != "zeros":
        raise ValueError("FakeQuant: ConvTranspose2d supports zero padding only")
    return F.conv_transpose2d(x, w, m.bias, m.stride, m.padding, m.output_padding, m.groups, m.dilation)  # type: ignore[arg-type]


def _linear(m: nn.Linear, x: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    return F.linear(x, w, m.bias)


#: The layers simulated (exactly these types: a subclass may compute something else).
_Weighted = nn.Conv2d | nn.ConvTranspose2d | nn.Linear
#: Layer type -> (its forward with a given weight, the weight's output-channel axis).
_FORWARDS: dict[type[nn.Module], tuple[Callable[..., torch.Tensor], int]] = {
    nn.Conv2d: (_conv, 0),
    nn.ConvTranspose2d: (_conv_transpose, 1),
    nn.Linear: (_linear, 0),
}


class FakeQuant:
    """Simulates int8 rounding in ``model``'s weighted layers outside ``keep_float`` (state-dict prefixes)."""

    def __init__(self, model: nn.Module, keep_float: Sequence[str] = (), weight_bits: int = WEIGHT_BITS) -> None:
        if weight_bits not in WEIGHT_QMAX:
            raise ValueError(f"FakeQuant: weight_bits {weight_bits}: expected one of {sorted(WEIGHT_QMAX)}")
        self.qmax = WEIGHT_QMAX[weight_bits]
        self.enabled = True
        names = [name for name, _ in model.named_modules()]
        for prefix in keep_float:
            if not any(under_module(name, prefix) for name in names):
                raise ValueError(f"FakeQuant: keep float {prefix!r}: no module of the model has that name")
        self.layers: dict[str, _Weighted] = {
            name: m
            for name, m in model.named_modules()
            if isinstance(m, _Weighted) and type(m) in _FORWARDS and not any(under_module(name, p) for p in keep_float)
        }
        if not self.layers:
            raise ValueError("FakeQuant: no Conv2d, ConvTranspose2d or Linear layer outside the float modules")
        self.ranges: dict[str, tuple[torch.Tensor, torch.Tensor]] = {}
        for name, m in self.layers.items():
            # an instance attribute over the class's forward, deleted again by remove()
            m.forward = self._forward_of(name, m)  # type: ignore[method-assign, assignment]

    def _forward_of(self, name: str, m: _Weighted) -> Callable[[torch.Tensor], torch.Tensor]:
        plain, axis = _FORWARDS[type(m)]
        per_position = isinstance(m, nn.ConvTranspose2d) and _rewritten_as_depth_to_space(m)

        def weight() -> torch.Tensor:
            w = m.weight
            if per_position:  # (in, out, k, k): one scale per (out, k, k), the 1x1 Conv's output channels
                return fake_quant_weight(w.flatten(1), 1, self.qmax).reshape(w.shape)
            return fake_quant_weight(w, axis, self.qmax)

        def forward(x: torch.Tensor) -> torch.Tensor:
            if not self.enabled:
                return plain(m, x, m.weight)
            return plain(m, self._activation(name, x, m.training), weight())

        return forward

    def _activation(self, name: str, x: torch.Tensor, training: bool) -> torch.Tensor:
        seen = self.ranges.get(name)
        if training or seen is None:
            low, high = percentile_range(x)
            if seen is not None:
                low = seen[0] + RANGE_MOMENTUM * (low - seen[0])
                high = seen[1] + RANGE_MOMENTUM * (high - seen[1])
            self.ranges[name] = seen = (low, high)
        return fake_quant_activation(x, *seen)

    def state(self) -> dict[str, list[float]]:
        """The running input ranges, for a checkpoint (a resumed run goes on with them)."""
        return {name: [float(low), float(high)] for name, (low, high) in self.ranges.items()}

    def load_state(self, state: dict[str, list[float]], device: torch.device) -> None:
        self.ranges = {
            name: (torch.tensor(low, device=device), torch.tensor(high, device=device))
            for name, (low, high) in state.items()
        }

    def remove(self) -> None:
        """Give every layer its own ``forward`` back."""
        for m in self.layers.values():
            del m.forward
        self.layers = {}
