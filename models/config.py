"""Typed configuration of FisheyeBEVDet with the defaults of the official ``configs/fisheye_bevdet.py``.

The configuration is a tree of frozen dataclasses so that a model, an exported artifact and a
checkpoint can be compared field by field. ``BEVDetConfig.from_mmdet3d_config`` reads an official
config file without executing it (see :mod:`.mmconfig`) and maps the mmdet3d dict onto it.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Mapping

from fisheye_infer.errors import ConfigError

from .mmconfig import read_mmdet3d_config

__all__ = ["ImageConfig", "BackboneConfig", "ViewTransformConfig", "BEVEncoderConfig", "HeadConfig",
           "BEVDetConfig", "FISHEYE3DOD_CLASSES", "from_mmdet3d_config"]

FISHEYE3DOD_CLASSES = ("Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist")
_CAMERAS = ("fisheye_camera_front", "fisheye_camera_left", "fisheye_camera_right", "fisheye_camera_rear")
Bound = tuple[float, float, float]


@dataclass(frozen=True)
class ImageConfig:
    """Input images and normalisation.

    ``mean``/``std`` are the ImageNet statistics in RGB order, applied as they are to the BGR
    channels (``bgr_to_rgb=False`` in the official preprocessor): channel 0 (blue) uses 123.675.
    """

    height: int = 800
    width: int = 800
    mean: tuple[float, float, float] = (123.675, 116.28, 103.53)
    std: tuple[float, float, float] = (58.395, 57.12, 57.375)
    bgr_to_rgb: bool = False
    camera_names: tuple[str, ...] = _CAMERAS


@dataclass(frozen=True)
class BackboneConfig:
    """mmdet ResNet + FPN; only FPN output 0 (stride 16) feeds the view transform.

    ``base_channels`` is mmdet ResNet's width (stage i has base_channels * 2**i channels); the
    official models use 64, the compact training configuration a narrower backbone.
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
class ViewTransformConfig:
    """FisheyeLSSTransform: equirectangular warp, depth/context head, lift and BEV mean pooling."""

    in_channels: int = 256
    out_channels: int = 96
    feature_size: tuple[int, int] = (25, 100)  # H_e x W_e of the angular grid
    azimuth_range: tuple[float, float] = (-math.radians(110.0), math.radians(110.0))
    elevation_range: tuple[float, float] = (-math.pi / 4, math.pi / 4)
    xbound: Bound = (-48.0, 48.0, 0.3)
    ybound: Bound = (-48.0, 48.0, 0.3)
    zbound: Bound = (-5.0, 5.0, 10.0)
    dbound: Bound = (0.5, 48.5, 0.5)
    ocam_fov: float = 220.0

    @property
    def num_depth_bins(self) -> int:
        start, stop, step = self.dbound
        return int(math.ceil((stop - start) / step))

    @property
    def bev_shape(self) -> tuple[int, int]:
        """(X, Y) cells, int((upper - lower) / step) as the official gen_dx_bx."""
        return (int((self.xbound[1] - self.xbound[0]) / self.xbound[2]),
                int((self.ybound[1] - self.ybound[0]) / self.ybound[2]))


@dataclass(frozen=True)
class BEVEncoderConfig:
    """SECOND + SECONDFPN (BN eps 1e-3)."""

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
    """TransFusionHead and its TransFusionBBoxCoder / test_cfg."""

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
        ("center", (2, 2)), ("height", (1, 2)), ("dim", (3, 2)), ("rot", (2, 2)))
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
        return (self.grid_size[0] // self.out_size_factor, self.grid_size[1] // self.out_size_factor)

    @property
    def unsuppressed_classes(self) -> tuple[int, ...]:
        """The Fisheye3DOD branch of the heatmap NMS leaves Pedestrian (4) and Cyclist (5) alone."""
        return (4, 5) if self.dataset == "Fisheye3DOD" else ()


@dataclass(frozen=True)
class BEVDetConfig:
    """Everything the FisheyeBEVDet graph depends on, except the rig."""

    image: ImageConfig = field(default_factory=ImageConfig)
    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    view_transform: ViewTransformConfig = field(default_factory=ViewTransformConfig)
    bev_encoder: BEVEncoderConfig = field(default_factory=BEVEncoderConfig)
    head: HeadConfig = field(default_factory=HeadConfig)
    class_names: tuple[str, ...] = FISHEYE3DOD_CLASSES

    def __post_init__(self) -> None:
        self.validate()

    def validate(self) -> None:
        """Cross-field consistency; each message names both fields."""
        vt, enc, head, bb = self.view_transform, self.bev_encoder, self.head, self.backbone
        stage_channels = tuple(bb.base_channels * 2 ** i for i in bb.out_indices)
        checks = [
            (tuple(bb.neck_in_channels) == stage_channels,
             f"backbone.neck_in_channels={tuple(bb.neck_in_channels)} != the channels of ResNet stages {tuple(bb.out_indices)} "
             f"with base_channels={bb.base_channels}: {stage_channels}"),
            (bb.neck_out_channels == vt.in_channels,
             f"backbone.neck_out_channels={bb.neck_out_channels} != view_transform.in_channels={vt.in_channels}"),
            (vt.out_channels == enc.in_channels,
             f"view_transform.out_channels={vt.out_channels} != bev_encoder.in_channels={enc.in_channels}"),
            (tuple(enc.out_channels) == tuple(enc.fpn_in_channels),
             f"bev_encoder.out_channels={enc.out_channels} != bev_encoder.fpn_in_channels={enc.fpn_in_channels}"),
            (sum(enc.fpn_out_channels) == head.in_channels,
             f"sum(bev_encoder.fpn_out_channels)={sum(enc.fpn_out_channels)} != head.in_channels={head.in_channels}"),
            (len(self.class_names) == head.num_classes,
             f"{len(self.class_names)} class_names but head.num_classes={head.num_classes}"),
            (len(self.image.mean) == 3 and len(self.image.std) == 3 and min(self.image.std) > 0,
             f"image.mean/std must be 3 values with std > 0, got {self.image.mean}, {self.image.std}"),
            (vt.zbound[1] > vt.zbound[0] and int((vt.zbound[1] - vt.zbound[0]) / vt.zbound[2]) == 1,
             f"view_transform.zbound={vt.zbound} must give exactly one z cell"),
        ]
        for ok, msg in checks:
            if not ok:
                raise ConfigError(f"inconsistent FisheyeBEVDet configuration: {msg}")
        x, y = vt.bev_shape
        s = enc.layer_strides[0]
        up0 = enc.upsample_strides[0]
        head_in = (int(x / s * up0), int(y / s * up0))
        if head_in != head.bev_size:
            raise ConfigError(f"inconsistent FisheyeBEVDet configuration: the BEV grid {x}x{y} reaches the head as "
                              f"{head_in[0]}x{head_in[1]}, but head.grid_size/out_size_factor gives "
                              f"{head.bev_size[0]}x{head.bev_size[1]}")
        for axis, bound in enumerate((vt.xbound, vt.ybound)):
            span = head.bev_size[axis] * head.out_size_factor * head.voxel_size[axis]
            if abs(head.pc_range[axis] - bound[0]) > 1e-6 or abs(span - (bound[1] - bound[0])) > 1e-6:
                raise ConfigError(f"inconsistent FisheyeBEVDet configuration: the head decodes axis {'xy'[axis]} over "
                                  f"[{head.pc_range[axis]}, {head.pc_range[axis] + span}] (pc_range, grid_size, "
                                  f"out_size_factor, voxel_size) but the BEV grid covers [{bound[0]}, {bound[1]}]")
        if head.num_proposals > head.num_classes * head.bev_size[0] * head.bev_size[1]:
            raise ConfigError(f"head.num_proposals={head.num_proposals} exceeds the heatmap size")

    # -- conversion ----------------------------------------------------------------------

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "BEVDetConfig":
        """Inverse of ``to_dict``; unknown fields are refused by name."""
        parts: dict[str, Any] = {}
        sub = {"image": ImageConfig, "backbone": BackboneConfig, "view_transform": ViewTransformConfig,
               "bev_encoder": BEVEncoderConfig, "head": HeadConfig}
        for key, value in data.items():
            if key in sub:
                parts[key] = _build(sub[key], value, key)
            elif key == "class_names":
                parts[key] = tuple(value)
            else:
                raise ConfigError(f"BEVDetConfig: unknown field '{key}'")
        return cls(**parts)

    def replace(self, **sections: Any) -> "BEVDetConfig":
        """Copy with whole sections or per-section field dicts replaced: ``cfg.replace(head={'num_proposals': 50})``."""
        updates: dict[str, Any] = {}
        for name, value in sections.items():
            current = getattr(self, name, None)
            if current is None:
                raise ConfigError(f"BEVDetConfig: unknown section '{name}'")
            updates[name] = dataclasses.replace(current, **value) if isinstance(value, Mapping) else value
        return dataclasses.replace(self, **updates)

    @classmethod
    def from_mmdet3d_config(cls, path: str | Path) -> "BEVDetConfig":
        """Read an official ``fisheye_bevdet.py``-style config (not executed) into a BEVDetConfig."""
        return cls.from_mmdet3d_dict(read_mmdet3d_config(path), source=str(path))

    @classmethod
    def from_mmdet3d_dict(cls, cfg: Mapping[str, Any], source: str = "<config>") -> "BEVDetConfig":
        return _from_mmdet3d(cls, cfg, source)


def from_mmdet3d_config(path: str | Path) -> BEVDetConfig:
    """Module-level spelling of :meth:`BEVDetConfig.from_mmdet3d_config`."""
    return BEVDetConfig.from_mmdet3d_config(path)


def _tuple(value: Any) -> Any:
    if isinstance(value, (list, tuple)):
        return tuple(_tuple(v) for v in value)
    return value


def _build(kind: type, values: Mapping[str, Any], where: str) -> Any:
    names = {f.name for f in dataclasses.fields(kind)}
    unknown = sorted(set(values) - names)
    if unknown:
        raise ConfigError(f"{where}: unknown field(s) {', '.join(unknown)}")
    converted = {}
    for key, value in values.items():
        if key == "common_heads" and isinstance(value, Mapping):
            value = tuple((k, tuple(v)) for k, v in value.items())
        converted[key] = _tuple(value)
    try:
        return kind(**converted)
    except TypeError as exc:
        raise ConfigError(f"{where}: {exc}") from None


class _Section:
    """Reads keys of one mmdet3d dict, naming the path in every error."""

    def __init__(self, data: Any, path: str, source: str) -> None:
        if not isinstance(data, Mapping):
            raise ConfigError(f"{source}: '{path}' must be a dict, got {type(data).__name__}")
        self.data, self.path, self.source = data, path, source

    def sub(self, key: str) -> "_Section":
        if key not in self.data:
            raise ConfigError(f"{self.source}: '{self.path}.{key}' is missing")
        return _Section(self.data[key], f"{self.path}.{key}", self.source)

    def get(self, key: str, default: Any) -> Any:
        return _tuple(self.data.get(key, default))

    def type_is(self, *allowed: str) -> None:
        kind = self.data.get("type")
        if kind is not None and kind not in allowed:
            raise ConfigError(f"{self.source}: '{self.path}.type' is '{kind}', expected one of {', '.join(allowed)}")


def _from_mmdet3d(cls: type[BEVDetConfig], cfg: Mapping[str, Any], source: str) -> BEVDetConfig:
    d = BEVDetConfig()
    model = _Section(cfg.get("model"), "model", source)
    model.type_is("BEVDet", "FisheyeBEVDet")
    pre = model.sub("data_preprocessor") if "data_preprocessor" in model.data else _Section({}, "model.data_preprocessor", source)
    bb, neck, vt = model.sub("img_backbone"), model.sub("img_neck"), model.sub("view_transform")
    enc, fpn, head = model.sub("pts_backbone"), model.sub("pts_neck"), model.sub("bbox_head")
    bb.type_is("mmdet.ResNet", "ResNet")
    neck.type_is("mmdet.FPN", "FPN")
    vt.type_is("FisheyeLSSTransform")
    enc.type_is("SECOND")
    fpn.type_is("SECONDFPN")
    head.type_is("TransFusionHead")
    coder = head.sub("bbox_coder") if "bbox_coder" in head.data else _Section({}, "model.bbox_head.bbox_coder", source)
    test = _Section(model.get("test_cfg", {}) or {}, "model.test_cfg", source)
    test_pts = _Section(test.get("pts", {}) or {}, "model.test_cfg.pts", source)
    test_pipeline = cfg.get("test_pipeline") or []
    cams = next((p.get("load_cam_names") for p in test_pipeline if isinstance(p, Mapping) and "load_cam_names" in p), None)

    image_size = vt.get("image_size", (d.image.height, d.image.width))
    image = ImageConfig(height=int(image_size[0]), width=int(image_size[1]),
                        mean=pre.get("mean", d.image.mean), std=pre.get("std", d.image.std),
                        bgr_to_rgb=bool(pre.get("bgr_to_rgb", d.image.bgr_to_rgb)),
                        camera_names=_tuple(cams) if cams else d.image.camera_names)
    if image.bgr_to_rgb:
        raise ConfigError(f"{source}: model.data_preprocessor.bgr_to_rgb=True is not supported "
                          "(the official models feed BGR with RGB-ordered statistics)")
    depth = bb.get("depth", 18)
    backbone = BackboneConfig(depth=depth, base_channels=int(bb.get("base_channels", 64)), strides=bb.get("strides", d.backbone.strides),
                              dilations=bb.get("dilations", d.backbone.dilations),
                              out_indices=bb.get("out_indices", d.backbone.out_indices),
                              neck_in_channels=neck.get("in_channels", d.backbone.neck_in_channels),
                              neck_out_channels=neck.get("out_channels", d.backbone.neck_out_channels),
                              neck_num_outs=neck.get("num_outs", d.backbone.neck_num_outs))
    for key, want in (("in_channels", 3), ("num_stages", 4)):
        if bb.get(key, want) != want:
            raise ConfigError(f"{source}: model.img_backbone.{key}={bb.get(key, want)} is not supported (expected {want})")
    view = ViewTransformConfig(
        in_channels=vt.get("in_channels", 256), out_channels=vt.get("out_channels", 96),
        feature_size=vt.get("feature_size", d.view_transform.feature_size),
        azimuth_range=vt.get("azimuth_range", d.view_transform.azimuth_range),
        elevation_range=vt.get("elevation_range", d.view_transform.elevation_range),
        xbound=vt.get("xbound", d.view_transform.xbound), ybound=vt.get("ybound", d.view_transform.ybound),
        zbound=vt.get("zbound", d.view_transform.zbound), dbound=vt.get("dbound", d.view_transform.dbound),
        ocam_fov=float(vt.get("ocam_fov", d.view_transform.ocam_fov)))
    if vt.get("downsample", 1) != 1:
        raise ConfigError(f"{source}: model.view_transform.downsample={vt.get('downsample', 1)} is not supported (expected 1)")
    for sec, key in ((enc, "norm_cfg"), (fpn, "norm_cfg")):
        eps = (sec.get(key, {}) or {}).get("eps", 1e-3)
        if eps != d.bev_encoder.bn_eps:
            raise ConfigError(f"{source}: {sec.path}.{key}.eps={eps} is not supported (expected 1e-3)")
    bev = BEVEncoderConfig(
        in_channels=enc.get("in_channels", 96), out_channels=enc.get("out_channels", (128, 256)),
        layer_nums=enc.get("layer_nums", (5, 5)), layer_strides=enc.get("layer_strides", (2, 2)),
        fpn_in_channels=fpn.get("in_channels", (128, 256)), fpn_out_channels=fpn.get("out_channels", (256, 256)),
        upsample_strides=fpn.get("upsample_strides", (1, 2)),
        use_conv_for_no_stride=bool(fpn.get("use_conv_for_no_stride", False)))
    layer = _Section(head.get("decoder_layer", {}) or {}, "model.bbox_head.decoder_layer", source)
    attn = layer.get("self_attn_cfg", {}) or {}
    ffn = layer.get("ffn_cfg", {}) or {}
    common = head.data.get("common_heads", dict(d.head.common_heads))
    grid = test_pts.get("grid_size", d.head.grid_size)
    hcfg = HeadConfig(
        in_channels=head.get("in_channels", 512), hidden_channel=head.get("hidden_channel", 128),
        num_classes=head.get("num_classes", 6), num_proposals=head.get("num_proposals", 200),
        nms_kernel_size=head.get("nms_kernel_size", 3), num_decoder_layers=head.get("num_decoder_layers", 1),
        num_heads=attn.get("num_heads", 8), ffn_channels=ffn.get("feedforward_channels", 256),
        head_conv=head.get("head_conv", 64),
        common_heads=tuple((k, _tuple(v)) for k, v in common.items()),
        dataset=test_pts.get("dataset", d.head.dataset), grid_size=grid,
        out_size_factor=test_pts.get("out_size_factor", coder.get("out_size_factor", 8)),
        voxel_size=tuple(coder.get("voxel_size", test_pts.get("voxel_size", d.head.voxel_size))[:2]),
        pc_range=tuple(coder.get("pc_range", test_pts.get("pc_range", d.head.pc_range))[:2]),
        post_center_range=coder.get("post_center_range", d.head.post_center_range),
        score_threshold=coder.get("score_threshold", 0.0), nms_type=test_pts.get("nms_type", None))
    coder_osf = coder.get("out_size_factor", hcfg.out_size_factor)
    if coder_osf != hcfg.out_size_factor:
        raise ConfigError(f"{source}: model.bbox_head.bbox_coder.out_size_factor={coder_osf} differs from "
                          f"model.test_cfg.pts.out_size_factor={hcfg.out_size_factor}")
    if hcfg.nms_type is not None:
        raise ConfigError(f"{source}: model.test_cfg.pts.nms_type={hcfg.nms_type!r} is not supported (expected None)")
    if hcfg.score_threshold:
        raise ConfigError(f"{source}: model.bbox_head.bbox_coder.score_threshold={hcfg.score_threshold} is not "
                          "supported (the official value 0.0 disables filtering)")
    classes = cfg.get("classes") or cfg.get("class_names") or d.class_names
    return cls(image=image, backbone=backbone, view_transform=view, bev_encoder=bev, head=hcfg,
               class_names=_tuple(classes))
