"""The sections every model configuration shares, and what a configuration records of its input.

`Preprocessing` is what a model takes and how it normalises it (what an exported file records);
`ImageConfig` and `BackboneConfig` are the ``image`` and ``backbone`` sections of every
configuration, `CylinderConfig` the rectified images of the cylindrical variants, and
`feature_size_of` the size of the backbone's feature map. The configurations built from them are in
[`config`][fisheye_infer.models.config].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS

__all__ = ["Preprocessing", "ImageConfig", "BackboneConfig", "CylinderConfig", "feature_size_of"]


@dataclass(frozen=True)
class Preprocessing:
    """What a model takes and how it normalises it: the facts an exported file records.

    Attributes:
        image_size (tuple[int, int]): (width, height) of every camera image, pixels.
        colour_order (Literal["BGR", "RGB"]): The order of the uint8 channels the model takes (OpenCV's BGR).
        mean (tuple[float, ...]): Per-channel mean subtracted, in channel order as applied.
        std (tuple[float, ...]): Per-channel standard deviation divided by.
        cameras (tuple[str, ...]): The camera order.
        classes (tuple[str, ...]): The label names, in class-index order.
    """

    image_size: tuple[int, int]
    colour_order: Literal["BGR", "RGB"]
    mean: tuple[float, ...]
    std: tuple[float, ...]
    cameras: tuple[str, ...]
    classes: tuple[str, ...]


@dataclass(frozen=True)
class ImageConfig:
    """Input images and normalisation.

    ``mean``/``std`` are the ImageNet statistics in RGB order, applied as they are to the BGR
    channels (``bgr_to_rgb=False`` in the official preprocessor): channel 0 (blue) uses 123.675.

    Attributes:
        height (int): Camera image height, pixels.
        width (int): Camera image width, pixels.
        mean (tuple[float, float, float]): Per-channel mean, applied to channels 0, 1, 2 as they come.
        std (tuple[float, float, float]): Per-channel standard deviation (> 0).
        bgr_to_rgb (bool): Swap the channels before normalising (the official models: False).
        camera_names (tuple[str, ...]): The cameras, in the model's input order (Fisheye3DOD's four by default).
    """

    height: int = 800
    width: int = 800
    mean: tuple[float, float, float] = (123.675, 116.28, 103.53)
    std: tuple[float, float, float] = (58.395, 57.12, 57.375)
    bgr_to_rgb: bool = False
    camera_names: tuple[str, ...] = FISHEYE3DOD_CAMERAS


@dataclass(frozen=True)
class BackboneConfig:
    """mmdet ResNet + FPN; only FPN output 0 (stride 16) is used.

    ``base_channels`` is mmdet ResNet's width (stage i has `base_channels * 2**i` channels); the
    official models use 64, the compact training configuration a narrower backbone.

    Attributes:
        depth (int): ResNet depth (18, 34, 50, ...).
        base_channels (int): Channels of the first stage.
        strides (tuple[int, int, int, int]): Stride of each stage.
        dilations (tuple[int, int, int, int]): Dilation of each stage.
        out_indices (tuple[int, ...]): The stages the FPN takes.
        neck_in_channels (tuple[int, ...]): Their channels (must equal the stages').
        neck_out_channels (int): FPN output channels.
        neck_num_outs (int): FPN output levels (only level 0 is used).
    """

    depth: int = 18
    base_channels: int = 64
    strides: tuple[int, int, int, int] = (1, 2, 2, 2)
    dilations: tuple[int, int, int, int] = (1, 1, 2, 4)
    out_indices: tuple[int, ...] = (2, 3)
    neck_in_channels: tuple[int, ...] = (256, 512)
    neck_out_channels: int = 256
    neck_num_outs: int = 2


@dataclass(frozen=True)
class CylinderConfig:
    """Size of the rectified cylindrical images (the pipeline's ``image_size=(W, H)``, here H x W)."""

    height: int = 400
    width: int = 800


def feature_size_of(image_hw: tuple[int, int], backbone: BackboneConfig | None = None) -> tuple[int, int]:
    """(H, W) of FPN level 0 for an (H, W) image: every stride-2 stage maps n to ceil(n / 2).

    The stem conv, the max pool and each stage's first conv all have padding (k - 1) / 2 (times the
    dilation), so a stride s maps n to (n - 1) // s + 1.
    """
    bb = backbone or BackboneConfig()
    strides = (2, 2, *bb.strides[: bb.out_indices[0] + 1])
    out = []
    for n in image_hw:
        for s in strides:
            n = (n - 1) // s + 1
        out.append(n)
    return (out[0], out[1])
