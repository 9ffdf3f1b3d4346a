"""Typed configuration of FisheyePETR with the defaults of the official ``configs/fisheye_petr.py``.

Every number the network or its decoder depends on lives here, so a model can be rebuilt from a
config alone and the export can copy the preprocessing facts into the artifact. Values that the
official config does not set are the head's constructor defaults (``depth_num=64``), because
that is what the released checkpoint was trained with.

    cfg = PETRConfig()                                   # official equirectangular FisheyePETR
    cfg = PETRConfig.from_mmdet3d_config("configs/fisheye_petr.py")
    small = dataclasses.replace(cfg, image_size=(160, 160), feature_size=(5, 21), num_query=40)
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Mapping

from fisheye_infer.errors import ConfigError

__all__ = ["PETRConfig", "CAMERA_NAMES", "CLASSES"]

CLASSES: tuple[str, ...] = ("Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist")
CAMERA_NAMES: tuple[str, ...] = (
    "fisheye_camera_front", "fisheye_camera_left", "fisheye_camera_right", "fisheye_camera_rear",
)
_HALF_FOV = math.radians(220 / 2)


@dataclass(frozen=True)
class PETRConfig:
    """FisheyePETR hyper-parameters (official defaults).

    Preprocessing: the official loader decodes BGR and normalises it with the RGB-ordered ImageNet
    statistics without swapping channels (``bgr_to_rgb=False``), so ``mean[0]``/``std[0]`` apply
    to the blue channel. ``channel_order`` records that the network expects BGR.

    Geometry: ``feature_size`` is the equirectangular grid the P3 features are warped onto;
    ``dbound`` only sizes the dead 96-slice ``frustum``/``sphere_grid_3d`` checkpoint tensors;
    the position embedding uses ``depth_num`` LID bins from ``depth_start`` to
    ``position_range[3]``.
    """

    classes: tuple[str, ...] = CLASSES
    camera_names: tuple[str, ...] = CAMERA_NAMES
    image_size: tuple[int, int] = (800, 800)  # H, W of every fisheye image
    mean: tuple[float, float, float] = (123.675, 116.28, 103.53)
    std: tuple[float, float, float] = (58.395, 57.12, 57.375)
    channel_order: str = "BGR"
    # backbone and neck (mmdet ResNet-18 with dilated stages, FPN on C3/C4)
    depth: int = 18
    strides: tuple[int, int, int, int] = (1, 2, 2, 2)
    dilations: tuple[int, int, int, int] = (1, 1, 2, 4)
    out_indices: tuple[int, ...] = (2, 3)
    neck_in_channels: tuple[int, ...] = (256, 512)
    neck_out_channels: int = 256
    neck_num_outs: int = 2
    # equirectangular warp
    cam_fov: float = 220.0
    feature_size: tuple[int, int] = (25, 100)  # H (elevation), W (azimuth)
    azimuth_range: tuple[float, float] = (-_HALF_FOV, _HALF_FOV)
    elevation_range: tuple[float, float] = (-math.pi / 4, math.pi / 4)
    dbound: tuple[float, float, float] = (0.5, 48.5, 0.5)
    # 3D position embedding
    depth_num: int = 64
    depth_start: float = 0.5
    lid: bool = True
    position_range: tuple[float, float, float, float, float, float] = (-60.0, -60.0, -10.0, 60.0, 60.0, 10.0)
    # transformer
    num_query: int = 900
    embed_dims: int = 256
    num_heads: int = 8
    num_layers: int = 6
    ffn_dims: int = 2048
    num_reg_fcs: int = 2
    pe_temperature: float = 10000.0
    # box coding
    code_size: int = 8
    point_cloud_range: tuple[float, float, float, float, float, float] = (-48.0, -48.0, -5.0, 48.0, 48.0, 5.0)
    post_center_range: tuple[float, float, float, float, float, float] = (-60.0, -60.0, -10.0, 60.0, 60.0, 10.0)
    max_num: int = 300

    def __post_init__(self) -> None:
        if self.channel_order not in ("BGR", "RGB"):
            raise ConfigError(f"channel_order: expected 'BGR' or 'RGB', got {self.channel_order!r}")
        if self.embed_dims % self.num_heads:
            raise ConfigError(f"embed_dims={self.embed_dims} is not divisible by num_heads={self.num_heads}")
        if self.embed_dims % 2:
            raise ConfigError(f"embed_dims={self.embed_dims} must be even (sine features are embed_dims/2 per axis)")
        if not self.lid:
            raise ConfigError("lid=False (uniform depth bins) is not supported; the Fisheye3DOD "
                              "FisheyePETR uses linear-increasing depths (LID=True)")
        if self.code_size != 8:
            raise ConfigError(f"code_size: only the 8-value layout [x,y,log dx,log dy,z,log dz,sin,cos] "
                              f"is supported, got {self.code_size}")
        if self.max_num > self.num_query * len(self.classes):
            raise ConfigError(f"max_num={self.max_num} exceeds num_query*num_classes="
                              f"{self.num_query * len(self.classes)}")
        if min(self.feature_size) < 2:
            raise ConfigError(f"feature_size must be at least 2x2, got {self.feature_size}")
        for name in ("position_range", "point_cloud_range", "post_center_range"):
            rng = getattr(self, name)
            if len(rng) != 6 or any(rng[i] >= rng[i + 3] for i in range(3)):
                raise ConfigError(f"{name}: expected [xmin, ymin, zmin, xmax, ymax, zmax], got {rng}")

    @property
    def num_classes(self) -> int:
        return len(self.classes)

    @property
    def num_cameras(self) -> int:
        return len(self.camera_names)

    @property
    def num_frustum_depths(self) -> int:
        """Slices of the (dead) ``frustum`` checkpoint tensor: ``len(arange(*dbound))``."""
        start, stop, step = self.dbound
        return max(0, math.ceil((stop - start) / step))

    def to_dict(self) -> dict[str, Any]:
        return dataclasses.asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> "PETRConfig":
        """Inverse of ``to_dict``; unknown fields are refused by name."""
        names = {f.name for f in dataclasses.fields(cls)}
        unknown = sorted(set(data) - names)
        if unknown:
            raise ConfigError(f"PETRConfig: unknown fields {', '.join(unknown)}")
        return cls(**{k: _tuple(v) for k, v in data.items()})

    @classmethod
    def from_mmdet3d_config(cls, path: str | Path) -> "PETRConfig":
        """Read an official mmdet3d python config (parsed safely, never executed).

        Only the fields this reimplementation uses are read; anything else in the file is
        ignored. A head type other than ``FisheyePETRHead`` is refused with ``ConfigError``
        because the cylindrical and pinhole variants need different geometry.
        """
        from .mmconfig import read_mmdet3d_config

        return cls.from_mmdet3d_dict(read_mmdet3d_config(path), source=str(path))

    @classmethod
    def from_mmdet3d_dict(cls, cfg: Mapping[str, Any], source: str = "<dict>") -> "PETRConfig":
        """Build from the top-level namespace of an official config (see ``from_mmdet3d_config``)."""
        model = _get(cfg, "model", source)
        head = _get(model, "pts_bbox_head", source, "model")
        head_type = head.get("type")
        if head_type != "FisheyePETRHead":
            raise ConfigError(f"{source}: model.pts_bbox_head.type is {head_type!r}; "
                              "only 'FisheyePETRHead' (equirectangular FisheyePETR) is supported")
        kw: dict[str, Any] = {}
        if "classes" in cfg:
            kw["classes"] = tuple(str(c) for c in cfg["classes"])
        pre = model.get("data_preprocessor", {})
        if "mean" in pre:
            kw["mean"] = _floats(pre["mean"], 3, "model.data_preprocessor.mean", source)
        if "std" in pre:
            kw["std"] = _floats(pre["std"], 3, "model.data_preprocessor.std", source)
        if pre.get("bgr_to_rgb", False) or pre.get("rgb_to_bgr", False):
            # The loader decodes BGR; a swap would make the network see RGB.
            kw["channel_order"] = "RGB"
        names = _camera_names(cfg)
        if names:
            kw["camera_names"] = names
        bb = model.get("img_backbone", {})
        for src, dst in (("depth", "depth"), ("strides", "strides"), ("dilations", "dilations"),
                         ("out_indices", "out_indices")):
            if src in bb:
                kw[dst] = int(bb[src]) if src == "depth" else tuple(int(v) for v in bb[src])
        neck = model.get("img_neck", {})
        if "in_channels" in neck:
            kw["neck_in_channels"] = tuple(int(v) for v in neck["in_channels"])
        if "out_channels" in neck:
            kw["neck_out_channels"] = int(neck["out_channels"])
        if "num_outs" in neck:
            kw["neck_num_outs"] = int(neck["num_outs"])
        simple = {"ocam_fov": ("cam_fov", float), "num_query": ("num_query", int),
                  "depth_num": ("depth_num", int), "depth_start": ("depth_start", float),
                  "LID": ("lid", bool), "code_size": ("code_size", int),
                  "num_reg_fcs": ("num_reg_fcs", int)}
        for src, (dst, typ) in simple.items():
            if src in head:
                kw[dst] = typ(head[src])
        tuples = {"feature_size": ("feature_size", 2, int), "azimuth_range": ("azimuth_range", 2, float),
                  "elevation_range": ("elevation_range", 2, float), "dbound": ("dbound", 3, float),
                  "position_range": ("position_range", 6, float)}
        for src, (dst, n, typ) in tuples.items():
            if src in head:
                vals = _floats(head[src], n, f"model.pts_bbox_head.{src}", source)
                kw[dst] = tuple(typ(v) for v in vals)
        if "num_classes" in head and "classes" in kw and int(head["num_classes"]) != len(kw["classes"]):
            raise ConfigError(f"{source}: pts_bbox_head.num_classes={head['num_classes']} but "
                              f"{len(kw['classes'])} class names are listed")
        _read_transformer(head.get("transformer", {}), kw, source)
        coder = head.get("bbox_coder", {})
        if "post_center_range" in coder:
            kw["post_center_range"] = _floats(coder["post_center_range"], 6, "bbox_coder.post_center_range", source)
        if "pc_range" in coder:
            kw["point_cloud_range"] = _floats(coder["pc_range"], 6, "bbox_coder.pc_range", source)
        if "max_num" in coder:
            kw["max_num"] = int(coder["max_num"])
        pe = head.get("positional_encoding", {})
        if "num_feats" in pe and "embed_dims" in kw and 2 * int(pe["num_feats"]) != kw["embed_dims"]:
            raise ConfigError(f"{source}: positional_encoding.num_feats={pe['num_feats']} must be embed_dims/2")
        if "temperature" in pe:
            kw["pe_temperature"] = float(pe["temperature"])
        return dataclasses.replace(cls(), **kw)


def _tuple(value: Any) -> Any:
    if isinstance(value, (list, tuple)):
        return tuple(_tuple(v) for v in value)
    return value


def _get(d: Mapping[str, Any], key: str, source: str, where: str = "") -> Mapping[str, Any]:
    value = d.get(key) if isinstance(d, Mapping) else None
    if not isinstance(value, Mapping):
        name = f"{where}.{key}" if where else key
        raise ConfigError(f"{source}: expected a dict at '{name}', got {type(value).__name__}")
    return value


def _floats(value: Any, n: int, name: str, source: str) -> tuple[float, ...]:
    try:
        vals = tuple(float(v) for v in value)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{source}: '{name}' must be {n} numbers, got {value!r}") from exc
    if len(vals) != n:
        raise ConfigError(f"{source}: '{name}' must have {n} values, got {len(vals)}")
    return vals


def _camera_names(cfg: Mapping[str, Any]) -> tuple[str, ...]:
    """Camera order of the test pipeline's multi-view loader (it fixes the order of cam2lidar)."""
    for step in cfg.get("test_pipeline", []) or []:
        if isinstance(step, Mapping) and "load_cam_names" in step:
            return tuple(str(n) for n in step["load_cam_names"])
    return ()


def _read_transformer(tr: Mapping[str, Any], kw: dict[str, Any], source: str) -> None:
    dec = tr.get("decoder", {}) if isinstance(tr, Mapping) else {}
    if "num_layers" in dec:
        kw["num_layers"] = int(dec["num_layers"])
    layer = dec.get("transformerlayers", {})
    if "feedforward_channels" in layer:
        kw["ffn_dims"] = int(layer["feedforward_channels"])
    order = layer.get("operation_order")
    expected = ("self_attn", "norm", "cross_attn", "norm", "ffn", "norm")
    if order is not None and tuple(order) != expected:
        raise ConfigError(f"{source}: decoder operation_order {tuple(order)} is not the post-norm order {expected}")
    attn = layer.get("attn_cfgs") or []
    if attn:
        first = attn[0]
        if "embed_dims" in first:
            kw["embed_dims"] = int(first["embed_dims"])
        if "num_heads" in first:
            kw["num_heads"] = int(first["num_heads"])
