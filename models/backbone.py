"""Image backbone and neck with mmdet's module names, so official checkpoints load by key.

The official detectors use mmdet's ``ResNet`` (depth 18, dilated last two stages) and ``FPN``.
torchvision's ``BasicBlock`` refuses dilation > 1 and names its modules differently, so both are
written here with the exact parameter names mmdet stores (``layerX.Y.conv1``, ``downsample.0/1``,
``lateral_convs.i.conv``, ``fpn_convs.i.conv``).
"""

from __future__ import annotations

from collections.abc import Sequence

import torch
import torch.nn.functional as F
from torch import nn

from fisheye_infer.errors import ConfigError

__all__ = ["BasicBlock", "ResNet", "FPN", "ConvModule2d"]

# depth -> blocks per stage; only the BasicBlock depths are used by the Fisheye3DOD models.
_ARCH: dict[int, tuple[int, int, int, int]] = {18: (2, 2, 2, 2), 34: (3, 4, 6, 3)}


class BasicBlock(nn.Module):
    """mmdet BasicBlock: conv1 carries stride and dilation (padding = dilation), conv2 is plain 3x3."""

    expansion = 1

    def __init__(
        self, inplanes: int, planes: int, stride: int = 1, dilation: int = 1, downsample: nn.Module | None = None
    ) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(inplanes, planes, 3, stride=stride, padding=dilation, dilation=dilation, bias=False)
        self.bn1 = nn.BatchNorm2d(planes, eps=1e-5)
        # conv2 is never dilated in mmdet's BasicBlock, even inside a dilated stage.
        self.conv2 = nn.Conv2d(planes, planes, 3, padding=1, bias=False)
        self.bn2 = nn.BatchNorm2d(planes, eps=1e-5)
        self.relu = nn.ReLU(inplace=False)
        self.downsample = downsample

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        identity = x if self.downsample is None else self.downsample(x)
        out = self.relu(self.bn1(self.conv1(x)))
        out = self.bn2(self.conv2(out))
        return self.relu(out + identity)


class ResNet(nn.Module):
    """mmdet ResNet (style 'pytorch', no deep stem, no avg-down), returning the stages in out_indices.

    For the Fisheye3DOD configuration (strides 1,2,2,2, dilations 1,1,2,4) an 800x800 input gives
    C3 = [256, 50, 50] and C4 = [512, 25, 25]: stride 16 for both outputs' parents, dilation keeps size.
    """

    def __init__(
        self,
        depth: int = 18,
        strides: Sequence[int] = (1, 2, 2, 2),
        dilations: Sequence[int] = (1, 1, 2, 4),
        out_indices: Sequence[int] = (2, 3),
        in_channels: int = 3,
        base_channels: int = 64,
    ) -> None:
        super().__init__()
        if depth not in _ARCH:
            raise ConfigError(f"ResNet depth {depth} is not supported (expected one of {sorted(_ARCH)})")
        if len(strides) != 4 or len(dilations) != 4:
            raise ConfigError(f"ResNet needs 4 strides and 4 dilations, got {tuple(strides)} and {tuple(dilations)}")
        if not out_indices or any(i not in range(4) for i in out_indices):
            raise ConfigError(f"ResNet out_indices must be within 0..3, got {tuple(out_indices)}")
        self.out_indices = tuple(int(i) for i in out_indices)
        self.conv1 = nn.Conv2d(in_channels, base_channels, 7, stride=2, padding=3, bias=False)
        self.bn1 = nn.BatchNorm2d(base_channels, eps=1e-5)
        self.relu = nn.ReLU(inplace=False)
        self.maxpool = nn.MaxPool2d(kernel_size=3, stride=2, padding=1)
        inplanes = base_channels
        self.out_channels: list[int] = []
        for i, (n_blocks, stride, dilation) in enumerate(zip(_ARCH[depth], strides, dilations)):
            planes = base_channels * 2**i
            layer = self._make_layer(inplanes, planes, n_blocks, int(stride), int(dilation))
            self.add_module(f"layer{i + 1}", layer)
            inplanes = planes * BasicBlock.expansion
            self.out_channels.append(inplanes)

    @staticmethod
    def _make_layer(inplanes: int, planes: int, n_blocks: int, stride: int, dilation: int) -> nn.Sequential:
        downsample = None
        if stride != 1 or inplanes != planes * BasicBlock.expansion:
            downsample = nn.Sequential(
                nn.Conv2d(inplanes, planes * BasicBlock.expansion, 1, stride=stride, bias=False),
                nn.BatchNorm2d(planes * BasicBlock.expansion, eps=1e-5),
            )
        blocks = [BasicBlock(inplanes, planes, stride, dilation, downsample)]
        blocks += [BasicBlock(planes, planes, 1, dilation) for _ in range(n_blocks - 1)]
        return nn.Sequential(*blocks)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, ...]:
        # x: M x 3 x H x W  (M = B*N views)
        x = self.maxpool(self.relu(self.bn1(self.conv1(x))))
        outs = []
        for i in range(4):
            x = getattr(self, f"layer{i + 1}")(x)
            if i in self.out_indices:
                outs.append(x)
        return tuple(outs)


class ConvModule2d(nn.Module):
    """A bare conv stored under ``.conv`` (mmcv ConvModule without norm/act) for key compatibility."""

    def __init__(self, in_ch: int, out_ch: int, kernel_size: int, padding: int = 0) -> None:
        super().__init__()
        self.conv = nn.Conv2d(in_ch, out_ch, kernel_size, padding=padding, bias=True)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.conv(x)


class FPN(nn.Module):
    """mmdet FPN with start_level 0, no extra convs, no norm/act and nearest upsampling to *size*.

    Extra outputs beyond the input levels (num_outs > len(in_channels)) are max_pool2d(k=1, s=2)
    of the last output, as mmdet does without add_extra_convs.
    """

    def __init__(self, in_channels: Sequence[int] = (256, 512), out_channels: int = 256, num_outs: int = 2) -> None:
        super().__init__()
        if num_outs < len(in_channels):
            raise ConfigError(f"FPN num_outs={num_outs} is smaller than the {len(in_channels)} input levels")
        self.num_outs = int(num_outs)
        self.lateral_convs = nn.ModuleList(ConvModule2d(c, out_channels, 1) for c in in_channels)
        self.fpn_convs = nn.ModuleList(ConvModule2d(out_channels, out_channels, 3, padding=1) for _ in in_channels)

    def forward(self, inputs: Sequence[torch.Tensor]) -> tuple[torch.Tensor, ...]:
        if len(inputs) != len(self.lateral_convs):
            raise ConfigError(f"FPN expects {len(self.lateral_convs)} inputs, got {len(inputs)}")
        laterals = [conv(x) for conv, x in zip(self.lateral_convs, inputs)]
        # Top-down: functional adds (no in-place writes) keep the graph export-friendly.
        for i in range(len(laterals) - 1, 0, -1):
            up = F.interpolate(laterals[i], size=laterals[i - 1].shape[-2:], mode="nearest")
            laterals[i - 1] = laterals[i - 1] + up
        outs = [conv(lat) for conv, lat in zip(self.fpn_convs, laterals)]
        while len(outs) < self.num_outs:
            outs.append(F.max_pool2d(outs[-1], 1, stride=2))
        return tuple(outs)
