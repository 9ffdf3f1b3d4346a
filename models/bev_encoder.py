"""BEV encoder: mmdet3d SECOND backbone and SECONDFPN neck, with mmdet3d's module indices.

Both use BatchNorm with eps 1e-3 (the Fisheye3DOD config passes ``eps=0.001``), unlike the image
backbone's 1e-5; loading an official checkpoint into a 1e-5 model would silently shift every
activation, so eps is a constructor argument with the official default.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
from torch import nn

from fisheye_infer.errors import ConfigError

__all__ = ["SECOND", "SECONDFPN"]


class SECOND(nn.Module):
    """Stacked conv stages; ``blocks.i`` = [conv(stride), BN, ReLU] + layer_nums[i] x [conv, BN, ReLU].

    Sequential indices match the checkpoint: conv at 0, 3, 6, ...; BN at 1, 4, 7, ...
    """

    def __init__(
        self,
        in_channels: int = 96,
        out_channels: Sequence[int] = (128, 256),
        layer_nums: Sequence[int] = (5, 5),
        layer_strides: Sequence[int] = (2, 2),
        bn_eps: float = 1e-3,
    ) -> None:
        super().__init__()
        if not (len(out_channels) == len(layer_nums) == len(layer_strides)):
            raise ConfigError(
                "SECOND out_channels, layer_nums and layer_strides must have equal length, got "
                f"{tuple(out_channels)}, {tuple(layer_nums)}, {tuple(layer_strides)}"
            )
        in_filters = [in_channels, *out_channels[:-1]]
        blocks = []
        for cin, cout, n, stride in zip(in_filters, out_channels, layer_nums, layer_strides):
            layers: list[nn.Module] = [
                nn.Conv2d(cin, cout, 3, stride=int(stride), padding=1, bias=False),
                nn.BatchNorm2d(cout, eps=bn_eps),
                nn.ReLU(inplace=False),
            ]
            for _ in range(int(n)):
                layers += [
                    nn.Conv2d(cout, cout, 3, padding=1, bias=False),
                    nn.BatchNorm2d(cout, eps=bn_eps),
                    nn.ReLU(inplace=False),
                ]
            blocks.append(nn.Sequential(*layers))
        self.blocks = nn.ModuleList(blocks)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        # x: B x C x X x Y  (BEV, rows = x forward)
        outs = []
        for block in self.blocks:
            x = block(x)
            outs.append(x)
        return tuple(outs)


class SECONDFPN(nn.Module):
    """Upsample each SECOND output to a common resolution and concatenate along channels.

    Stride > 1: ConvTranspose2d(k=s, s=s); stride 1 with use_conv_for_no_stride: Conv2d(k=1);
    stride < 1: Conv2d(k=1/s, s=1/s). All without bias, then BN and ReLU.
    """

    def __init__(
        self,
        in_channels: Sequence[int] = (128, 256),
        out_channels: Sequence[int] = (256, 256),
        upsample_strides: Sequence[float] = (1, 2),
        use_conv_for_no_stride: bool = True,
        bn_eps: float = 1e-3,
    ) -> None:
        super().__init__()
        if not (len(in_channels) == len(out_channels) == len(upsample_strides)):
            raise ConfigError(
                "SECONDFPN in_channels, out_channels and upsample_strides must have equal "
                f"length, got {tuple(in_channels)}, {tuple(out_channels)}, {tuple(upsample_strides)}"
            )
        deblocks = []
        for cin, cout, stride in zip(in_channels, out_channels, upsample_strides):
            if stride > 1 or (stride == 1 and not use_conv_for_no_stride):
                k = int(stride)
                up: nn.Module = nn.ConvTranspose2d(cin, cout, k, stride=k, bias=False)
            else:
                k = int(round(1.0 / stride))
                up = nn.Conv2d(cin, cout, k, stride=k, bias=False)
            deblocks.append(nn.Sequential(up, nn.BatchNorm2d(cout, eps=bn_eps), nn.ReLU(inplace=False)))
        self.deblocks = nn.ModuleList(deblocks)

    def forward(self, xs: Sequence[torch.Tensor]) -> torch.Tensor:
        if len(xs) != len(self.deblocks):
            raise ConfigError(f"SECONDFPN expects {len(self.deblocks)} inputs, got {len(xs)}")
        ups = [deblock(x) for deblock, x in zip(self.deblocks, xs)]
        # B x sum(out_channels) x X' x Y'
        return torch.cat(ups, dim=1) if len(ups) > 1 else ups[0]
