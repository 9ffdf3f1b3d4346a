"""Typed configuration of FisheyeBEVDet with the defaults of the official ``configs/fisheye_bevdet.py``.

A tree of frozen dataclasses (see [`config`][fisheye_infer.models.config]): ``image``, ``backbone``, ``view_transform``,
``bev_encoder``, ``head`` and ``class_names``. ``BEVDetConfig.from_mmdet3d_config`` reads an
official config file without executing it and maps the mmdet3d dict onto it; the cylindrical
variant ([`cyl_config`][fisheye_infer.models.cyl_config]) changes only how the view transform is read.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.lss import LSSParams
from fisheye_infer.runtime.records import CLASSES

from .bevdet_sections import BEVEncoderConfig, HeadConfig, ViewTransformConfig
from .config import BackboneConfig, ImageConfig, ModelConfig, feature_size_of, read_backbone, read_classes, read_image
from .mmconfig import Section, as_tuple

__all__ = ["ViewTransformConfig", "BEVEncoderConfig", "HeadConfig", "BEVDetConfig"]


@dataclass(frozen=True)
class BEVDetConfig(ModelConfig):
    """Everything the FisheyeBEVDet graph depends on, except the rig (official defaults).

    Attributes:
        image (ImageConfig): Input images and normalisation.
        backbone (BackboneConfig): The image backbone (ResNet) and neck (FPN).
        view_transform (ViewTransformConfig): The LSS view transform: the angular feature grid, the depth bins
            (``dbound``, metres) and the BEV grid (``xbound``, ``ybound``, ``zbound``: lower, upper, step in
            metres).
        bev_encoder (BEVEncoderConfig): The BEV encoder (SECOND + SECONDFPN).
        head (HeadConfig): The TransFusion head: ``num_proposals`` (the boxes per frame), classes, decoding
            ranges.
        class_names (tuple[str, ...]): The label names, in class-index order (``head.num_classes`` of them).

    Raises:
        ConfigError: Inconsistent sections (each message names both fields).

    Examples:
        ```python
        from fisheye_infer.models import BEVDetConfig, create_model

        cfg = BEVDetConfig.from_mmdet3d_config("configs/fisheye_bevdet.py")
        fewer = cfg.replace(head={"num_proposals": 100})
        model = create_model("fisheye-bevdet", fewer)
        ```
    """

    image: ImageConfig = field(default_factory=ImageConfig)
    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    view_transform: ViewTransformConfig = field(default_factory=ViewTransformConfig)
    bev_encoder: BEVEncoderConfig = field(default_factory=BEVEncoderConfig)
    head: HeadConfig = field(default_factory=HeadConfig)
    class_names: tuple[str, ...] = CLASSES

    def validate(self) -> None:
        """Check cross-field consistency (called when the configuration is made).

        Raises:
            ConfigError: Inconsistent fields; each message names both.
        """
        vt, enc, head, bb = self.view_transform, self.bev_encoder, self.head, self.backbone
        stage_channels = tuple(bb.base_channels * 2**i for i in bb.out_indices)
        checks = [
            (
                tuple(bb.neck_in_channels) == stage_channels,
                f"backbone.neck_in_channels={tuple(bb.neck_in_channels)} != the channels of ResNet stages "
                f"{tuple(bb.out_indices)} with base_channels={bb.base_channels}: {stage_channels}",
            ),
            (
                bb.neck_out_channels == vt.in_channels,
                f"backbone.neck_out_channels={bb.neck_out_channels} != view_transform.in_channels={vt.in_channels}",
            ),
            (
                vt.out_channels == enc.in_channels,
                f"view_transform.out_channels={vt.out_channels} != bev_encoder.in_channels={enc.in_channels}",
            ),
            (
                tuple(enc.out_channels) == tuple(enc.fpn_in_channels),
                f"bev_encoder.out_channels={enc.out_channels} != bev_encoder.fpn_in_channels={enc.fpn_in_channels}",
            ),
            (
                sum(enc.fpn_out_channels) == head.in_channels,
                f"sum(bev_encoder.fpn_out_channels)={sum(enc.fpn_out_channels)} != head.in_channels={head.in_channels}",
            ),
            (
                len(self.class_names) == head.num_classes,
                f"{len(self.class_names)} class_names but head.num_classes={head.num_classes}",
            ),
            (
                not self.image.bgr_to_rgb,
                "image.bgr_to_rgb=True is not supported (the official models feed BGR with RGB-ordered statistics)",
            ),
            (
                len(self.image.mean) == 3 and len(self.image.std) == 3 and min(self.image.std) > 0,
                f"image.mean/std must be 3 values with std > 0, got {self.image.mean}, {self.image.std}",
            ),
            (
                vt.zbound[1] > vt.zbound[0] and int((vt.zbound[1] - vt.zbound[0]) / vt.zbound[2]) == 1,
                f"view_transform.zbound={vt.zbound} must give exactly one z cell",
            ),
        ]
        for ok, msg in checks:
            if not ok:
                raise ConfigError(f"inconsistent FisheyeBEVDet configuration: {msg}")
        x, y = vt.bev_shape
        s = enc.layer_strides[0]
        up0 = enc.upsample_strides[0]
        head_in = (int(x / s * up0), int(y / s * up0))
        if head_in != head.bev_size:
            raise ConfigError(
                f"inconsistent FisheyeBEVDet configuration: the BEV grid {x}x{y} reaches the head as "
                f"{head_in[0]}x{head_in[1]}, but head.grid_size/out_size_factor gives "
                f"{head.bev_size[0]}x{head.bev_size[1]}"
            )
        for axis, bound in enumerate((vt.xbound, vt.ybound)):
            span = head.bev_size[axis] * head.out_size_factor * head.voxel_size[axis]
            if abs(head.pc_range[axis] - bound[0]) > 1e-6 or abs(span - (bound[1] - bound[0])) > 1e-6:
                raise ConfigError(
                    f"inconsistent FisheyeBEVDet configuration: the head decodes axis {'xy'[axis]} over "
                    f"[{head.pc_range[axis]}, {head.pc_range[axis] + span}] (pc_range, grid_size, "
                    f"out_size_factor, voxel_size) but the BEV grid covers [{bound[0]}, {bound[1]}]"
                )
        if head.num_proposals > head.num_classes * head.bev_size[0] * head.bev_size[1]:
            raise ConfigError(f"head.num_proposals={head.num_proposals} exceeds the heatmap size")

    @property
    def num_boxes(self) -> int:
        """Boxes per frame the model outputs (``head.num_proposals``)."""
        return self.head.num_proposals

    def geometry_params(self) -> Any:
        """The parameters of the model's ``geom.*`` tables (what an exported file records and re-baking reads).

        Returns:
            Any: The LSS parameters (`LSSParams`).
        """
        vt = self.view_transform
        return LSSParams(
            feature_size=tuple(vt.feature_size),
            azimuth_range=tuple(vt.azimuth_range),
            elevation_range=tuple(vt.elevation_range),
            source_size=feature_size_of((self.image.height, self.image.width), self.backbone),
            dbound=tuple(vt.dbound),
            xbound=tuple(vt.xbound),
            ybound=tuple(vt.ybound),
            zbound=tuple(vt.zbound),
        )

    # -- reading an official file ---------------------------------------------------------

    @classmethod
    def from_mmdet3d_dict(cls, cfg: Mapping[str, Any], source: str = "<config>") -> Any:
        """Read an official ``fisheye_bevdet.py``-style namespace (see ``from_mmdet3d_config``).

        Args:
            cfg (Mapping[str, Any]): The namespace, as
                [`read_mmdet3d_config`][fisheye_infer.models.mmconfig.read_mmdet3d_config] returns it.
            source (str): What error messages call it (the file name).

        Returns:
            BEVDetConfig: The configuration.

        Raises:
            ConfigError: Another model type, or a value this implementation does not support (named with its
                key).
        """
        d = cls()
        model = Section(cfg.get("model"), "model", source)
        model.type_is("BEVDet", "FisheyeBEVDet")
        vt, enc, fpn, head = (
            model.sub("view_transform"),
            model.sub("pts_backbone"),
            model.sub("pts_neck"),
            model.sub("bbox_head"),
        )
        enc.type_is("SECOND")
        fpn.type_is("SECONDFPN")
        head.type_is("TransFusionHead")
        image = read_image(model, cfg, *cls._image_size(vt, d, cfg), d.image)
        if image.bgr_to_rgb:
            raise ConfigError(
                f"{source}: model.data_preprocessor.bgr_to_rgb=True is not supported "
                "(the official models feed BGR with RGB-ordered statistics)"
            )
        if vt.get("downsample", 1) != 1:
            raise vt.refuse("downsample", 1, vt.get("downsample"))
        return cls(
            image=image,
            backbone=read_backbone(model, d.backbone),
            **cls._read_view_transform(vt, cfg, d),
            bev_encoder=_read_bev_encoder(enc, fpn, d.bev_encoder),
            head=_read_head(model, head, d.head),
            class_names=read_classes(cfg, d.class_names),
        )

    @classmethod
    def _image_size(cls, vt: Section, d: BEVDetConfig, cfg: Mapping[str, Any]) -> tuple[int, int]:
        """(H, W) of the camera images: the view transform's ``image_size``."""
        h, w = vt.get("image_size", (d.image.height, d.image.width))
        return int(h), int(w)

    @classmethod
    def _read_view_transform(cls, vt: Section, cfg: Mapping[str, Any], d: BEVDetConfig) -> dict[str, Any]:
        """The sections the view transform defines: here ``view_transform`` (a ``FisheyeLSSTransform``)."""
        vt.type_is("FisheyeLSSTransform")
        return {
            "view_transform": ViewTransformConfig(
                **view_transform_fields(vt, d.view_transform),
                azimuth_range=vt.get("azimuth_range", d.view_transform.azimuth_range),
                elevation_range=vt.get("elevation_range", d.view_transform.elevation_range),
            )
        }


def view_transform_fields(vt: Section, d: ViewTransformConfig) -> dict[str, Any]:
    """The view transform's fields that the spherical and the cylindrical transforms share."""
    return dict(
        in_channels=vt.get("in_channels", d.in_channels),
        out_channels=vt.get("out_channels", d.out_channels),
        feature_size=vt.get("feature_size", d.feature_size),
        xbound=vt.get("xbound", d.xbound),
        ybound=vt.get("ybound", d.ybound),
        zbound=vt.get("zbound", d.zbound),
        dbound=vt.get("dbound", d.dbound),
        ocam_fov=float(vt.get("ocam_fov", d.ocam_fov)),
    )


def _read_bev_encoder(enc: Section, fpn: Section, d: BEVEncoderConfig) -> BEVEncoderConfig:
    for sec in (enc, fpn):
        eps = (sec.get("norm_cfg", {}) or {}).get("eps", 1e-3)
        if eps != d.bn_eps:
            raise sec.refuse("norm_cfg.eps", d.bn_eps, eps)
    return BEVEncoderConfig(
        in_channels=enc.get("in_channels", 96),
        out_channels=enc.get("out_channels", (128, 256)),
        layer_nums=enc.get("layer_nums", (5, 5)),
        layer_strides=enc.get("layer_strides", (2, 2)),
        fpn_in_channels=fpn.get("in_channels", (128, 256)),
        fpn_out_channels=fpn.get("out_channels", (256, 256)),
        upsample_strides=fpn.get("upsample_strides", (1, 2)),
        use_conv_for_no_stride=bool(fpn.get("use_conv_for_no_stride", False)),
    )


def _read_head(model: Section, head: Section, d: HeadConfig) -> HeadConfig:
    coder = head.sub("bbox_coder", required=False)
    test_pts = model.sub("test_cfg", required=False).sub("pts", required=False)
    layer = head.sub("decoder_layer", required=False)
    attn, ffn = layer.sub("self_attn_cfg", required=False), layer.sub("ffn_cfg", required=False)
    common = head.data.get("common_heads", dict(d.common_heads))
    hcfg = HeadConfig(
        in_channels=head.get("in_channels", 512),
        hidden_channel=head.get("hidden_channel", 128),
        num_classes=head.get("num_classes", 6),
        num_proposals=head.get("num_proposals", 200),
        nms_kernel_size=head.get("nms_kernel_size", 3),
        num_decoder_layers=head.get("num_decoder_layers", 1),
        num_heads=attn.get("num_heads", 8),
        ffn_channels=ffn.get("feedforward_channels", 256),
        head_conv=head.get("head_conv", 64),
        common_heads=tuple((k, as_tuple(v)) for k, v in common.items()),
        dataset=test_pts.get("dataset", d.dataset),
        grid_size=test_pts.get("grid_size", d.grid_size),
        out_size_factor=test_pts.get("out_size_factor", coder.get("out_size_factor", 8)),
        voxel_size=tuple(coder.get("voxel_size", test_pts.get("voxel_size", d.voxel_size))[:2]),
        pc_range=tuple(coder.get("pc_range", test_pts.get("pc_range", d.pc_range))[:2]),
        post_center_range=coder.get("post_center_range", d.post_center_range),
        score_threshold=coder.get("score_threshold", 0.0),
        nms_type=test_pts.get("nms_type", None),
    )
    coder_osf = coder.get("out_size_factor", hcfg.out_size_factor)
    if coder_osf != hcfg.out_size_factor:
        raise ConfigError(
            f"{head.source}: model.bbox_head.bbox_coder.out_size_factor={coder_osf} differs from "
            f"model.test_cfg.pts.out_size_factor={hcfg.out_size_factor}"
        )
    if hcfg.nms_type is not None:
        raise test_pts.refuse("nms_type", None, hcfg.nms_type)
    if hcfg.score_threshold:
        raise coder.refuse("score_threshold", 0.0, hcfg.score_threshold, "; the official value disables filtering")
    return hcfg
