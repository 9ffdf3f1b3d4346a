"""The sections of the FisheyeBEVDet configuration, with the defaults of the official ``configs/fisheye_bevdet.py``.

`ViewTransformConfig` (the LSS view transform), `BEVEncoderConfig` (SECOND + SECONDFPN) and
`HeadConfig` (the TransFusion head) are frozen dataclasses; the configuration made of them, and
read from official files, is [`BEVDetConfig`][fisheye_infer.models.bevdet_config.BEVDetConfig].
"""

from __future__ import annotations

import math
from dataclasses import dataclass

__all__ = ["ViewTransformConfig", "BEVEncoderConfig", "HeadConfig"]

Bound = tuple[float, float, float]


@dataclass(frozen=True)
class ViewTransformConfig:
    """FisheyeLSSTransform: equirectangular warp, depth/context head, lift and BEV mean pooling.

    Attributes:
        in_channels (int): Channels of the image features (the neck's output).
        out_channels (int): Channels of the lifted context features (the BEV encoder's input).
        feature_size (tuple[int, int]): (H, W) of the angular grid the features are warped onto (elevation,
            azimuth).
        azimuth_range (tuple[float, float]): Azimuths the grid spans, radians.
        elevation_range (tuple[float, float]): Elevations the grid spans, radians.
        xbound (tuple[float, float, float]): BEV grid along x: lower, upper, step, metres.
        ybound (tuple[float, float, float]): BEV grid along y: lower, upper, step, metres.
        zbound (tuple[float, float, float]): The one z cell: lower, upper, step, metres.
        dbound (tuple[float, float, float]): Depth bins along each ray: start, stop, step, metres.
        ocam_fov (float): The lens's full field of view the warp assumes, degrees.
    """

    in_channels: int = 256
    out_channels: int = 96
    feature_size: tuple[int, int] = (25, 100)
    azimuth_range: tuple[float, float] = (-math.radians(110.0), math.radians(110.0))
    elevation_range: tuple[float, float] = (-math.pi / 4, math.pi / 4)
    xbound: Bound = (-48.0, 48.0, 0.3)
    ybound: Bound = (-48.0, 48.0, 0.3)
    zbound: Bound = (-5.0, 5.0, 10.0)
    dbound: Bound = (0.5, 48.5, 0.5)
    ocam_fov: float = 220.0

    @property
    def num_depth_bins(self) -> int:
        """Depth bins per ray: ``ceil((stop - start) / step)`` of ``dbound``."""
        start, stop, step = self.dbound
        return int(math.ceil((stop - start) / step))

    @property
    def bev_shape(self) -> tuple[int, int]:
        """(X, Y) cells, int((upper - lower) / step) as the official gen_dx_bx."""
        return (
            int((self.xbound[1] - self.xbound[0]) / self.xbound[2]),
            int((self.ybound[1] - self.ybound[0]) / self.ybound[2]),
        )


@dataclass(frozen=True)
class BEVEncoderConfig:
    """SECOND + SECONDFPN (BN eps 1e-3).

    Attributes:
        in_channels (int): Channels of the BEV features (the view transform's output).
        out_channels (tuple[int, ...]): Channels of each SECOND stage.
        layer_nums (tuple[int, ...]): Convolutions per stage.
        layer_strides (tuple[int, ...]): Stride of each stage.
        fpn_in_channels (tuple[int, ...]): Channels the FPN takes (the stages').
        fpn_out_channels (tuple[int, ...]): Channels of each FPN output; their sum is the head's input.
        upsample_strides (tuple[float, ...]): Upsampling of each FPN branch.
        use_conv_for_no_stride (bool): A convolution rather than a transposed one where the stride is 1.
        bn_eps (float): BatchNorm epsilon.
    """

    in_channels: int = 96
    out_channels: tuple[int, ...] = (128, 256)
    layer_nums: tuple[int, ...] = (5, 5)
    layer_strides: tuple[int, ...] = (2, 2)
    fpn_in_channels: tuple[int, ...] = (128, 256)
    fpn_out_channels: tuple[int, ...] = (256, 256)
    upsample_strides: tuple[float, ...] = (1, 2)
    use_conv_for_no_stride: bool = True
    bn_eps: float = 1e-3


@dataclass(frozen=True)
class HeadConfig:
    """TransFusionHead and its TransFusionBBoxCoder / test_cfg.

    Attributes:
        in_channels (int): Channels of the BEV features (the FPN outputs' sum).
        hidden_channel (int): Channels inside the head.
        num_classes (int): Classes of the heatmap (``len(class_names)``).
        num_proposals (int): Boxes per frame: the heatmap peaks taken as queries.
        nms_kernel_size (int): Size of the heatmap's local-maximum window.
        num_decoder_layers (int): Transformer decoder layers.
        num_heads (int): Attention heads.
        ffn_channels (int): Feed-forward channels of the decoder.
        head_conv (int): Channels of the prediction branches.
        common_heads (tuple[tuple[str, tuple[int, int]], ...]): Each regression branch: name, (output channels,
            convolutions).
        dataset (str): ``"Fisheye3DOD"`` leaves Pedestrian and Cyclist out of the heatmap NMS.
        grid_size (tuple[int, int, int]): The voxel grid (X, Y, Z) the head decodes against.
        out_size_factor (int): Voxels per BEV cell.
        voxel_size (tuple[float, float]): Voxel size along x and y, metres.
        pc_range (tuple[float, float]): Lower x and y of the grid, metres.
        post_center_range (tuple[float, float, float, float, float, float]): Box centres kept: x, y, z minimum
            then maximum, metres.
        score_threshold (float): Must be 0 (the official value, no filtering).
        nms_type (str | None): Must be None (no box NMS at test time).
    """

    in_channels: int = 512
    hidden_channel: int = 128
    num_classes: int = 6
    num_proposals: int = 200
    nms_kernel_size: int = 3
    num_decoder_layers: int = 1
    num_heads: int = 8
    ffn_channels: int = 256
    head_conv: int = 64
    common_heads: tuple[tuple[str, tuple[int, int]], ...] = (
        ("center", (2, 2)),
        ("height", (1, 2)),
        ("dim", (3, 2)),
        ("rot", (2, 2)),
    )
    dataset: str = "Fisheye3DOD"
    grid_size: tuple[int, int, int] = (1280, 1280, 40)
    out_size_factor: int = 8
    voxel_size: tuple[float, float] = (0.075, 0.075)
    pc_range: tuple[float, float] = (-48.0, -48.0)
    post_center_range: tuple[float, float, float, float, float, float] = (-50.0, -50.0, -5.0, 50.0, 50.0, 5.0)
    score_threshold: float = 0.0
    nms_type: str | None = None

    @property
    def bev_size(self) -> tuple[int, int]:
        """(X, Y) cells of the heatmap: ``grid_size[:2] // out_size_factor``."""
        return (self.grid_size[0] // self.out_size_factor, self.grid_size[1] // self.out_size_factor)

    @property
    def unsuppressed_classes(self) -> tuple[int, ...]:
        """The Fisheye3DOD branch of the heatmap NMS leaves Pedestrian (4) and Cyclist (5) alone."""
        return (4, 5) if self.dataset == "Fisheye3DOD" else ()
