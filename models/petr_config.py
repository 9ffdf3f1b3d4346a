"""Typed configuration of FisheyePETR with the defaults of the official ``configs/fisheye_petr.py``.

The same shape as every configuration (see [`config`][fisheye_infer.models.config]): ``image``, ``backbone``, ``head``
(everything ``pts_bbox_head`` sets: the warp, the 3D position embedding, the transformer and the
box coder) and ``class_names``. Values that the official config does not set are the head's
constructor defaults (``depth_num=64``), because that is what the released checkpoint was trained
with.

    cfg = PETRConfig()                                   # official equirectangular FisheyePETR
    cfg = PETRConfig.from_mmdet3d_config("configs/fisheye_petr.py")
    small = cfg.replace(image={"height": 160, "width": 160},
                        head={"feature_size": (5, 21), "num_query": 40, "max_num": 40})
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.petr import PETRParams
from fisheye_infer.runtime.records import CLASSES

from .config import (
    BackboneConfig,
    ImageConfig,
    ModelConfig,
    feature_size_of,
    read_backbone,
    read_classes,
    read_image,
    written_image_size,
)
from .mmconfig import Section

__all__ = ["PETRHeadConfig", "PETRConfig"]

_HALF_FOV = math.radians(220 / 2)
_POST_NORM_ORDER = ("self_attn", "norm", "cross_attn", "norm", "ffn", "norm")


@dataclass(frozen=True)
class PETRHeadConfig:
    """``FisheyePETRHead``: the feature warp, the 3D position embedding, the decoder and NMSFreeCoder.

    Geometry: ``feature_size`` is the equirectangular grid the P3 features are warped onto;
    ``dbound`` only sizes the dead 96-slice ``frustum``/``sphere_grid_3d`` checkpoint tensors;
    the position embedding uses ``depth_num`` LID bins from ``depth_start`` to
    ``position_range[3]``.

    Attributes:
        cam_fov (float): The lens's full field of view the warp assumes, degrees.
        feature_size (tuple[int, int]): (H, W) of the equirectangular feature grid (elevation, azimuth).
        azimuth_range (tuple[float, float]): Azimuths the grid spans, radians.
        elevation_range (tuple[float, float]): Elevations the grid spans, radians.
        dbound (tuple[float, float, float]): Start, stop, step of the checkpoint's ``frustum`` depths, metres.
        depth_num (int): Depth bins of the 3D position embedding.
        depth_start (float): The first bin's depth, metres.
        lid (bool): Linear-increasing bin spacing; must be True (uniform bins are not supported).
        position_range (tuple[float, float, float, float, float, float]): The box the embedded 3D points are
            normalised to: x, y, z minimum then maximum, metres.
        num_query (int): Object queries of the decoder.
        embed_dims (int): Transformer width (divisible by ``num_heads``).
        num_heads (int): Attention heads.
        num_layers (int): Decoder layers.
        ffn_dims (int): Feed-forward channels.
        num_reg_fcs (int): Linear layers of the regression branch.
        pe_temperature (float): Temperature of the sinusoidal embedding of the reference points.
        code_size (int): Length of a box's regression code.
        point_cloud_range (tuple[float, float, float, float, float, float]): The range box centres are decoded
            in: x, y, z minimum then maximum, metres.
        post_center_range (tuple[float, float, float, float, float, float]): Box centres kept, likewise.
        max_num (int): Boxes per frame (at most ``num_query * num_classes``).
    """

    cam_fov: float = 220.0
    feature_size: tuple[int, int] = (25, 100)
    azimuth_range: tuple[float, float] = (-_HALF_FOV, _HALF_FOV)
    elevation_range: tuple[float, float] = (-math.pi / 4, math.pi / 4)
    dbound: tuple[float, float, float] = (0.5, 48.5, 0.5)
    depth_num: int = 64
    depth_start: float = 0.5
    lid: bool = True
    position_range: tuple[float, float, float, float, float, float] = (-60.0, -60.0, -10.0, 60.0, 60.0, 10.0)
    num_query: int = 900
    embed_dims: int = 256
    num_heads: int = 8
    num_layers: int = 6
    ffn_dims: int = 2048
    num_reg_fcs: int = 2
    pe_temperature: float = 10000.0
    code_size: int = 8
    point_cloud_range: tuple[float, float, float, float, float, float] = (-48.0, -48.0, -5.0, 48.0, 48.0, 5.0)
    post_center_range: tuple[float, float, float, float, float, float] = (-60.0, -60.0, -10.0, 60.0, 60.0, 10.0)
    max_num: int = 300

    @property
    def num_frustum_depths(self) -> int:
        """Slices of the (dead) ``frustum`` checkpoint tensor: ``len(arange(*dbound))``."""
        start, stop, step = self.dbound
        return max(0, math.ceil((stop - start) / step))


@dataclass(frozen=True)
class PETRConfig(ModelConfig):
    """FisheyePETR hyper-parameters (official defaults).

    Preprocessing: the official loader decodes BGR and normalises it with the RGB-ordered ImageNet
    statistics without swapping channels (``image.bgr_to_rgb=False``), so ``mean[0]``/``std[0]``
    apply to the blue channel; ``bgr_to_rgb=True`` swaps the channels before normalising.

    Attributes:
        image (ImageConfig): Input images and normalisation.
        backbone (BackboneConfig): The image backbone (ResNet) and neck (FPN).
        head (PETRHeadConfig): Everything ``pts_bbox_head`` sets: the equirectangular feature warp
            (``feature_size``, ``cam_fov`` in degrees), the 3D position embedding (``depth_num`` bins from
            ``depth_start`` metres), the transformer (``num_query``, ``embed_dims``, ``num_layers``) and the box
            coder (``max_num``: the boxes per frame).
        class_names (tuple[str, ...]): The label names, in class-index order.

    Raises:
        ConfigError: Inconsistent sections (each message names the fields).

    Examples:
        ```python
        from fisheye_infer.models import PETRConfig, create_model

        cfg = PETRConfig()                                   # the official equirectangular FisheyePETR
        small = cfg.replace(image={"height": 160, "width": 160},
                        head={"feature_size": (5, 21), "num_query": 40, "max_num": 40})
        model = create_model("fisheye-petr", small)
        ```
    """

    image: ImageConfig = field(default_factory=ImageConfig)
    backbone: BackboneConfig = field(default_factory=BackboneConfig)
    head: PETRHeadConfig = field(default_factory=PETRHeadConfig)
    class_names: tuple[str, ...] = CLASSES

    def validate(self) -> None:
        """Check cross-field consistency (called when the configuration is made).

        Raises:
            ConfigError: Inconsistent fields, each message naming them.
        """
        h = self.head
        if h.embed_dims % h.num_heads:
            raise ConfigError(f"head.embed_dims={h.embed_dims} is not divisible by head.num_heads={h.num_heads}")
        if h.embed_dims % 2:
            raise ConfigError(f"head.embed_dims={h.embed_dims} must be even (sine features are embed_dims/2 per axis)")
        if not h.lid:
            raise ConfigError(
                "head.lid=False (uniform depth bins) is not supported; the Fisheye3DOD "
                "FisheyePETR uses linear-increasing depths (LID=True)"
            )
        if h.code_size != 8:
            raise ConfigError(
                f"head.code_size: only the 8-value layout [x,y,log dx,log dy,z,log dz,sin,cos] "
                f"is supported, got {h.code_size}"
            )
        if h.max_num > h.num_query * self.num_classes:
            raise ConfigError(
                f"head.max_num={h.max_num} exceeds num_query*num_classes={h.num_query * self.num_classes}"
            )
        if min(h.feature_size) < 2:
            raise ConfigError(f"head.feature_size must be at least 2x2, got {h.feature_size}")
        for name in ("position_range", "point_cloud_range", "post_center_range"):
            rng = getattr(h, name)
            if len(rng) != 6 or any(rng[i] >= rng[i + 3] for i in range(3)):
                raise ConfigError(f"head.{name}: expected [xmin, ymin, zmin, xmax, ymax, zmax], got {rng}")

    @property
    def num_boxes(self) -> int:
        """Boxes per frame the model outputs (``head.max_num``)."""
        return self.head.max_num

    def geometry_params(self) -> Any:
        """The parameters of the model's ``geom.*`` tables (what an exported file records and re-baking reads).

        Returns:
            Any: The PETR parameters (`PETRParams`).
        """
        h = self.head
        return PETRParams(
            feature_size=tuple(h.feature_size),
            azimuth_range=tuple(h.azimuth_range),
            elevation_range=tuple(h.elevation_range),
            source_size=feature_size_of((self.image.height, self.image.width), self.backbone),
            depth_num=h.depth_num,
            depth_start=h.depth_start,
            position_range=tuple(h.position_range),
            num_feats=h.embed_dims // 2,
            temperature=h.pe_temperature,
        )

    # -- reading an official file ---------------------------------------------------------

    @classmethod
    def from_mmdet3d_dict(cls, cfg: Mapping[str, Any], source: str = "<config>") -> Any:
        """Read an official ``fisheye_petr.py``-style namespace (see ``from_mmdet3d_config``).

        Only the fields this reimplementation uses are read; anything else in the file is ignored.

        Args:
            cfg (Mapping[str, Any]): The namespace, as
                [`read_mmdet3d_config`][fisheye_infer.models.mmconfig.read_mmdet3d_config] returns it.
            source (str): What error messages call it (the file name).

        Returns:
            PETRConfig: The configuration.

        Raises:
            ConfigError: Another model type, or a value this implementation does not support (named with its
                key).
        """
        d = cls()
        model = Section(cfg.get("model"), "model", source)
        head = model.sub("pts_bbox_head")
        classes = read_classes(cfg, d.class_names)
        if "num_classes" in head and int(head.get("num_classes")) != len(classes):
            raise ConfigError(
                f"{source}: pts_bbox_head.num_classes={head.get('num_classes')} but {len(classes)} class names are "
                "listed"
            )
        sections = cls._read_head(head, cfg, d)
        return cls(
            image=read_image(model, cfg, *cls._image_size(head, d, cfg), d.image),
            backbone=read_backbone(model, d.backbone, required=False),
            **sections,
            class_names=classes,
        )

    @classmethod
    def _image_size(cls, head: Section, d: PETRConfig, cfg: Mapping[str, Any]) -> tuple[int, int]:
        """(H, W) of the camera images: the top-level ``image_size`` of a file ``fisheye-infer train`` wrote;
        official files do not state it (Fisheye3DOD: 800 x 800, the size of the OCam calibration)."""
        return written_image_size(cfg, d.image, head.source)

    @classmethod
    def _read_head(cls, head: Section, cfg: Mapping[str, Any], d: PETRConfig) -> dict[str, Any]:
        """The sections the head defines: here ``head`` (a ``FisheyePETRHead``)."""
        head.type_is("FisheyePETRHead", required=True)
        fields = head_fields(head, d.head)
        for key, n in (("feature_size", 2), ("azimuth_range", 2), ("elevation_range", 2)):
            if key in head:
                fields[key] = head.numbers(key, n, int if key == "feature_size" else float)
        return {"head": PETRHeadConfig(**fields)}


def head_fields(head: Section, d: PETRHeadConfig) -> dict[str, Any]:
    """The head's fields that the spherical and the cylindrical heads share (all but the warp's)."""
    out: dict[str, Any] = {f: getattr(d, f) for f in PETRHeadConfig.__dataclass_fields__}
    for src, (dst, kind) in {
        "ocam_fov": ("cam_fov", float),
        "num_query": ("num_query", int),
        "depth_num": ("depth_num", int),
        "depth_start": ("depth_start", float),
        "LID": ("lid", bool),
        "code_size": ("code_size", int),
        "num_reg_fcs": ("num_reg_fcs", int),
    }.items():
        if src in head:
            out[dst] = kind(head.data[src])
    for key, n in (("dbound", 3), ("position_range", 6)):
        if key in head:
            out[key] = head.numbers(key, n)
    decoder = head.sub("transformer", required=False).sub("decoder", required=False)
    if "num_layers" in decoder:
        out["num_layers"] = int(decoder.data["num_layers"])
    layer = decoder.sub("transformerlayers", required=False)
    if "feedforward_channels" in layer:
        out["ffn_dims"] = int(layer.data["feedforward_channels"])
    order = layer.get("operation_order")
    if order is not None and tuple(order) != _POST_NORM_ORDER:
        raise ConfigError(
            f"{head.source}: decoder operation_order {tuple(order)} is not the post-norm order {_POST_NORM_ORDER}"
        )
    attn = layer.get("attn_cfgs") or ()
    if attn:
        first = attn[0]
        if "embed_dims" in first:
            out["embed_dims"] = int(first["embed_dims"])
        if "num_heads" in first:
            out["num_heads"] = int(first["num_heads"])
    coder = head.sub("bbox_coder", required=False)
    if "post_center_range" in coder:
        out["post_center_range"] = coder.numbers("post_center_range", 6)
    if "pc_range" in coder:
        out["point_cloud_range"] = coder.numbers("pc_range", 6)
    if "max_num" in coder:
        out["max_num"] = int(coder.data["max_num"])
    pe = head.sub("positional_encoding", required=False)
    if "num_feats" in pe and 2 * int(pe.data["num_feats"]) != out["embed_dims"]:
        raise ConfigError(f"{head.source}: positional_encoding.num_feats={pe.data['num_feats']} must be embed_dims/2")
    if "temperature" in pe:
        out["pe_temperature"] = float(pe.data["temperature"])
    return out
