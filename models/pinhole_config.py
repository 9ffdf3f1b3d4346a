"""Configurations of the pinhole baselines: ``nusc_bevdet.py``, ``fisheye_to_pinhole_bevdet.py``,
``nusc_petr.py`` and ``fisheye_to_pinhole_petr.py``.

BEVDet with the standard ``LSSTransform`` and PETR with the standard ``PETRHead``, on pinhole
views; they differ in where the views come from, read from the official test pipeline:

- pinhole cameras (``PinholeBEVDetConfig``, ``PinholePETRConfig``): six 1280x720 images, each
  resized by PIL's bicubic filter and cropped (``ImageAug3D`` / ``ResizeCropFlipImage`` in test
  mode: crop ``int((1 - mean(bot_pct_lim)) * newH) - fH`` rows from the top, centred horizontally;
  the scale is ``mean(resize_lim)`` for ``ImageAug3D``, ``max(fH / H, fW / W)`` for
  ``ResizeCropFlipImage``);
- perspective views of fisheye cameras (``PerspBEVDetConfig``, ``PerspPETRConfig``): four 800x800
  images, each rectified into ``len(yaws)`` views by ``MultiViewFisheyePerspectiveProjection``; an
  ``ImageAug3D`` after it (BEVDet's, same size, scale 1) truncates the float views to uint8
  (``truncate``), PETR's pipeline has none.

``image`` is the raw input the graph takes; ``view_transform.image_size`` / ``head.image_size`` is
the views' size.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fisheye_infer.cameras.rig import PINHOLE_CAMERAS
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.pinhole_lss import PinholeLSSParams
from fisheye_infer.geometry.pinhole_petr import PinholePETRParams
from fisheye_infer.geometry.views import Perspective, ResizeCrop

from .bevdet_config import BEVDetConfig, ViewTransformConfig, view_transform_fields
from .config import ImageConfig, feature_size_of, read_backbone
from .mmconfig import Section
from .petr_config import PETRConfig, PETRHeadConfig, head_fields

__all__ = [
    "PinholeViewTransformConfig",
    "ImageAugConfig",
    "PerspectiveConfig",
    "PinholeBEVDetConfig",
    "PerspBEVDetConfig",
    "PinholePETRHeadConfig",
    "PinholePETRConfig",
    "PerspPETRConfig",
    "PERSPECTIVE_STEP",
    "IMAGE_AUG_STEP",
    "RESIZE_CROP_STEP",
]

PERSPECTIVE_STEP = "MultiViewFisheyePerspectiveProjection"
IMAGE_AUG_STEP = "ImageAug3D"
RESIZE_CROP_STEP = "ResizeCropFlipImage"


@dataclass(frozen=True)
class PinholeViewTransformConfig(ViewTransformConfig):
    """``LSSTransform``: depthnet on the stride-16 features of each view, the image-plane frustum.

    ``image_size`` (H, W) is the views' size (the frustum's pixel range), ``feature_size`` their
    stride-16 features; the angular fields of :class:`ViewTransformConfig` play no part.
    """

    image_size: tuple[int, int] = (400, 800)
    feature_size: tuple[int, int] = (25, 50)


@dataclass(frozen=True)
class ImageAugConfig:
    """``ImageAug3D`` in test mode: resize by ``scale``, crop a ``final_dim`` (H, W) window at (left, top) ``crop``."""

    scale: float = 0.625
    crop: tuple[int, int] = (0, 50)

    def views(self) -> ResizeCrop:
        return ResizeCrop(scale=self.scale, crop=tuple(self.crop))


@dataclass(frozen=True)
class PerspectiveConfig:
    """``MultiViewFisheyePerspectiveProjection``: views of ``size`` (H, W), ``fov`` degrees, one per yaw (degrees).

    ``truncate``: the views are cast to uint8 (floor) before normalisation, as a following
    ``ImageAug3D`` does; without it the float remap output is normalised.
    """

    size: tuple[int, int] = (400, 400)
    fov: float = 110.0
    yaws: tuple[float, ...] = (-55.0, 55.0)
    truncate: bool = True

    def views(self) -> Perspective:
        return Perspective(size=tuple(self.size), fov=self.fov, yaws=tuple(self.yaws))


def _pinhole_view_transform(vt: Section, d: PinholeViewTransformConfig) -> PinholeViewTransformConfig:
    vt.type_is("LSSTransform", required=True)
    size = vt.numbers("image_size", 2, int) if "image_size" in vt else d.image_size
    return PinholeViewTransformConfig(**view_transform_fields(vt, d), image_size=size)


def _check_views(
    section: str, image_size: tuple[int, int], feature_size: tuple[int, int], view_size: tuple[int, int], backbone: Any
) -> None:
    """The section's image size is the views' size, and its feature map their stride-16 features."""
    if tuple(image_size) != tuple(view_size):
        raise ConfigError(f"{section}.image_size={tuple(image_size)} but the views are {tuple(view_size)} (H, W)")
    expected = feature_size_of(tuple(image_size), backbone)  # type: ignore[arg-type]
    if tuple(feature_size) != expected:
        raise ConfigError(
            f"{section}.feature_size={tuple(feature_size)} but {image_size[0]}x{image_size[1]} views "
            f"give stride-16 features of {expected[0]}x{expected[1]}"
        )


def _check_crop(image: ImageConfig, aug: ImageAugConfig, view_size: tuple[int, int]) -> None:
    """The crop lies inside the resized image."""
    (vh, vw), (left, top) = view_size, aug.crop
    rw, rh = ResizeCrop(scale=aug.scale).resized_size(image.width, image.height) if aug.scale > 0 else (0, 0)
    if aug.scale <= 0 or left < 0 or top < 0 or left + vw > rw or top + vh > rh:
        raise ConfigError(
            f"image_aug: a {vw}x{vh} crop at (left, top)={tuple(aug.crop)} does not fit the {rw}x{rh} image that "
            f"scale={aug.scale} makes of the {image.width}x{image.height} input"
        )


def _test_mode_crop(scale: float, width: int, height: int, final: tuple[int, int], bot_pct: float) -> ImageAugConfig:
    """The official test-mode crop: the bottom ``final`` rows above ``bot_pct`` of the resized height,
    centred columns."""
    new_w, new_h = ResizeCrop(scale=scale).resized_size(width, height)
    fh, fw = final
    return ImageAugConfig(scale=scale, crop=(int(max(0, new_w - fw) / 2), int((1 - bot_pct) * new_h) - fh))


def _steps(cfg: Mapping[str, Any], kind: str) -> list[Mapping[str, Any]]:
    return [s for s in cfg.get("test_pipeline") or [] if isinstance(s, Mapping) and s.get("type") == kind]


def _mean(section: Section, key: str, default: tuple[float, float]) -> float:
    lo, hi = section.numbers(key, 2) if key in section else default
    return (lo + hi) / 2.0


@dataclass(frozen=True)
class PinholeBEVDetConfig(BEVDetConfig):
    """BEVDet on six pinhole cameras: ``image`` the raw 1280x720 input, ``image_aug`` the resize and crop."""

    image: ImageConfig = field(
        default_factory=lambda: ImageConfig(height=720, width=1280, camera_names=PINHOLE_CAMERAS)
    )
    view_transform: PinholeViewTransformConfig = field(default_factory=PinholeViewTransformConfig)
    image_aug: ImageAugConfig = field(default_factory=ImageAugConfig)

    def validate(self) -> None:
        super().validate()
        vt = self.view_transform
        _check_views("view_transform", vt.image_size, vt.feature_size, vt.image_size, self.backbone)
        _check_crop(self.image, self.image_aug, vt.image_size)

    def views(self) -> ResizeCrop:
        return self.image_aug.views()

    def geometry_params(self) -> Any:
        vt = self.view_transform
        return PinholeLSSParams(
            feature_size=tuple(vt.feature_size),
            image_size=tuple(vt.image_size),
            source_size=(self.image.height, self.image.width),
            views=self.views(),
            dbound=tuple(vt.dbound),
            xbound=tuple(vt.xbound),
            ybound=tuple(vt.ybound),
            zbound=tuple(vt.zbound),
        )

    @classmethod
    def _image_size(cls, vt: Section, d: BEVDetConfig) -> tuple[int, int]:
        """The raw camera size is not in the file (the official converter's 1280x720)."""
        return d.image.height, d.image.width

    @classmethod
    def _read_view_transform(cls, vt: Section, cfg: Mapping[str, Any], d: BEVDetConfig) -> dict[str, Any]:
        """``view_transform`` (an ``LSSTransform``) and ``image_aug`` from the test pipeline's ``ImageAug3D``."""
        if _steps(cfg, PERSPECTIVE_STEP):
            raise ConfigError(
                f"{vt.source}: the test pipeline rectifies fisheye images ({PERSPECTIVE_STEP}): a fisheye-bevdet-persp "
                "configuration, not a pinhole-camera one"
            )
        view = _pinhole_view_transform(vt, d.view_transform)  # type: ignore[arg-type]
        steps = _steps(cfg, IMAGE_AUG_STEP)
        if not steps:
            return {"view_transform": view, "image_aug": d.image_aug}  # type: ignore[attr-defined]
        step = Section(steps[0], f"test_pipeline.{IMAGE_AUG_STEP}", vt.source)
        if step.get("is_train", False):
            raise step.refuse(
                "is_train", False, True, "; the test pipeline's augmentation must be the deterministic one"
            )
        fh, fw = step.numbers("final_dim", 2, int)
        if (fh, fw) != tuple(view.image_size):
            raise ConfigError(
                f"{vt.source}: {step.where('final_dim')}={(fh, fw)} differs from "
                f"{vt.where('image_size')}={view.image_size}"
            )
        aug = _test_mode_crop(
            _mean(step, "resize_lim", (1.0, 1.0)),
            d.image.width,
            d.image.height,
            (fh, fw),
            _mean(step, "bot_pct_lim", (0.0, 0.0)),
        )
        return {"view_transform": view, "image_aug": aug}


@dataclass(frozen=True)
class PerspBEVDetConfig(BEVDetConfig):
    """BEVDet on perspective views rectified from four fisheye cameras: ``image`` the raw 800x800 fisheye input."""

    view_transform: PinholeViewTransformConfig = field(
        default_factory=lambda: PinholeViewTransformConfig(image_size=(400, 400), feature_size=(25, 25))
    )
    perspective: PerspectiveConfig = field(default_factory=PerspectiveConfig)

    def validate(self) -> None:
        super().validate()
        vt = self.view_transform
        _check_views("view_transform", vt.image_size, vt.feature_size, self.perspective.size, self.backbone)
        if not self.perspective.yaws:
            raise ConfigError("perspective.yaws: expected at least one view per camera")

    @property
    def num_views(self) -> int:
        return self.num_cameras * len(self.perspective.yaws)

    def views(self) -> Perspective:
        return self.perspective.views()

    def geometry_params(self) -> Any:
        vt = self.view_transform
        return PinholeLSSParams(
            feature_size=tuple(vt.feature_size),
            image_size=tuple(vt.image_size),
            source_size=(self.image.height, self.image.width),
            views=self.views(),
            dbound=tuple(vt.dbound),
            xbound=tuple(vt.xbound),
            ybound=tuple(vt.ybound),
            zbound=tuple(vt.zbound),
        )

    @classmethod
    def _image_size(cls, vt: Section, d: BEVDetConfig) -> tuple[int, int]:
        """The raw fisheye size is not in the file (Fisheye3DOD: 800 x 800; the model refuses a rig whose
        camera differs)."""
        return d.image.height, d.image.width

    @classmethod
    def _read_view_transform(cls, vt: Section, cfg: Mapping[str, Any], d: BEVDetConfig) -> dict[str, Any]:
        """``view_transform`` (an ``LSSTransform``) and ``perspective`` from the test pipeline's rectification step."""
        steps = _steps(cfg, PERSPECTIVE_STEP)
        if not steps:
            raise ConfigError(
                f"{vt.source}: the test pipeline has no {PERSPECTIVE_STEP} step: not a perspective-rectified "
                "fisheye configuration"
            )
        view = _pinhole_view_transform(vt, d.view_transform)  # type: ignore[arg-type]
        return {
            "view_transform": view,
            "perspective": read_perspective(cfg, Section(steps[0], f"test_pipeline.{PERSPECTIVE_STEP}", vt.source)),
        }


def read_perspective(cfg: Mapping[str, Any], step: Section) -> PerspectiveConfig:
    """The rectification step and whether an ``ImageAug3D`` after it truncates the views to uint8.

    That ``ImageAug3D`` must leave the views as they are (same ``final_dim``, scale 1): anything
    else would be a resize this configuration does not describe.
    """
    d = PerspectiveConfig()
    w, h = step.numbers("image_size", 2, int) if "image_size" in step else d.size[::-1]
    yaws = tuple(float(y) for y in step.get("camera_orientation", d.yaws))
    count = int(step.get("num_imgs_of_per_view", len(yaws)))
    if count != len(yaws):
        raise ConfigError(
            f"{step.source}: {step.where('num_imgs_of_per_view')}={count} but {step.where('camera_orientation')} "
            f"has {len(yaws)} yaws"
        )
    augs = _steps(cfg, IMAGE_AUG_STEP)
    for aug in augs:
        s = Section(aug, f"test_pipeline.{IMAGE_AUG_STEP}", step.source)
        if tuple(s.numbers("final_dim", 2, int)) != (h, w) or _mean(s, "resize_lim", (1.0, 1.0)) != 1.0:
            raise ConfigError(
                f"{step.source}: {s.where('final_dim')}/{s.where('resize_lim')} resize the {h}x{w} perspective views; "
                "only the identity (the uint8 cast) is supported after the rectification"
            )
    return PerspectiveConfig(size=(h, w), fov=float(step.get("perspective_fov", d.fov)), yaws=yaws, truncate=bool(augs))


# -- PETR ------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PinholePETRHeadConfig(PETRHeadConfig):
    """``PETRHead``: keys on the stride-16 features of each view; ``image_size`` (H, W) is the views' size (the
    padded input the key pixels are spread over: the released configs pad to a divisor of 1). The
    equirectangular fields of :class:`PETRHeadConfig` play no part."""

    image_size: tuple[int, int] = (400, 800)
    feature_size: tuple[int, int] = (25, 50)


def _pinhole_head(
    head: Section, d: PinholePETRHeadConfig, image_size: tuple[int, int], backbone: Any
) -> PinholePETRHeadConfig:
    head.type_is("PETRHead", required=True)
    fields = head_fields(head, d)
    return PinholePETRHeadConfig(
        **{**fields, "image_size": tuple(image_size), "feature_size": feature_size_of(image_size, backbone)}
    )


def _pinhole_petr_params(cfg: PETRConfig, views: ResizeCrop | Perspective) -> PinholePETRParams:
    h = cfg.head
    return PinholePETRParams(
        feature_size=tuple(h.feature_size),
        image_size=tuple(h.image_size),  # type: ignore[attr-defined]
        source_size=(cfg.image.height, cfg.image.width),
        views=views,
        depth_num=h.depth_num,
        depth_start=h.depth_start,
        position_range=tuple(h.position_range),
        num_feats=h.embed_dims // 2,
        temperature=h.pe_temperature,
    )


def _backbone_of(cfg: Mapping[str, Any], source: str, d: PETRConfig) -> Any:
    return read_backbone(Section(cfg.get("model"), "model", source), d.backbone, required=False)


@dataclass(frozen=True)
class PinholePETRConfig(PETRConfig):
    """PETR on six pinhole cameras: ``image`` the raw 1280x720 input, ``image_aug`` the resize and crop."""

    image: ImageConfig = field(
        default_factory=lambda: ImageConfig(height=720, width=1280, camera_names=PINHOLE_CAMERAS)
    )
    head: PinholePETRHeadConfig = field(default_factory=PinholePETRHeadConfig)
    image_aug: ImageAugConfig = field(default_factory=ImageAugConfig)

    def validate(self) -> None:
        super().validate()
        h = self.head
        _check_views("head", h.image_size, h.feature_size, h.image_size, self.backbone)
        _check_crop(self.image, self.image_aug, h.image_size)

    def views(self) -> ResizeCrop:
        return self.image_aug.views()

    def geometry_params(self) -> Any:
        return _pinhole_petr_params(self, self.views())

    @classmethod
    def _image_size(cls, head: Section, d: PETRConfig) -> tuple[int, int]:
        """The raw camera size: ``ResizeCropFlipImage``'s ``H`` and ``W`` where the file has them, else 1280x720."""
        return d.image.height, d.image.width

    @classmethod
    def _read_head(cls, head: Section, cfg: Mapping[str, Any], d: PETRConfig) -> dict[str, Any]:
        """``head`` (a ``PETRHead``) and ``image_aug`` from the test pipeline's ``ResizeCropFlipImage``."""
        if _steps(cfg, PERSPECTIVE_STEP):
            raise ConfigError(
                f"{head.source}: the test pipeline rectifies fisheye images ({PERSPECTIVE_STEP}): a fisheye-petr-persp "
                "configuration, not a pinhole-camera one"
            )
        steps = _steps(cfg, RESIZE_CROP_STEP)
        if not steps:
            raise ConfigError(
                f"{head.source}: the test pipeline has no {RESIZE_CROP_STEP} step: not a pinhole-camera PETR "
                "configuration"
            )
        step = Section(steps[0], f"test_pipeline.{RESIZE_CROP_STEP}", head.source)
        if step.get("training", False):
            raise step.refuse(
                "training", False, True, "; the test pipeline's augmentation must be the deterministic one"
            )
        conf = step.sub("data_aug_conf")
        fh, fw = conf.numbers("final_dim", 2, int)
        height, width = int(conf.get("H", d.image.height)), int(conf.get("W", d.image.width))
        if (height, width) != (d.image.height, d.image.width):
            raise ConfigError(
                f"{head.source}: {conf.where('H')}/{conf.where('W')}={height}x{width}: the pinhole cameras are "
                f"{d.image.height}x{d.image.width} (the official converter's size)"
            )
        aug = _test_mode_crop(
            max(fh / height, fw / width), width, height, (fh, fw), _mean(conf, "bot_pct_lim", (0.0, 0.0))
        )
        return {"head": _pinhole_head(head, d.head, (fh, fw), _backbone_of(cfg, head.source, d)), "image_aug": aug}  # type: ignore[arg-type]


@dataclass(frozen=True)
class PerspPETRConfig(PETRConfig):
    """PETR on perspective views rectified from four fisheye cameras: ``image`` the raw 800x800 fisheye input."""

    head: PinholePETRHeadConfig = field(
        default_factory=lambda: PinholePETRHeadConfig(image_size=(400, 400), feature_size=(25, 25))
    )
    perspective: PerspectiveConfig = field(default_factory=lambda: PerspectiveConfig(truncate=False))

    def validate(self) -> None:
        super().validate()
        h = self.head
        _check_views("head", h.image_size, h.feature_size, self.perspective.size, self.backbone)
        if not self.perspective.yaws:
            raise ConfigError("perspective.yaws: expected at least one view per camera")

    @property
    def num_views(self) -> int:
        return self.num_cameras * len(self.perspective.yaws)

    def views(self) -> Perspective:
        return self.perspective.views()

    def geometry_params(self) -> Any:
        return _pinhole_petr_params(self, self.views())

    @classmethod
    def _read_head(cls, head: Section, cfg: Mapping[str, Any], d: PETRConfig) -> dict[str, Any]:
        """``head`` (a ``PETRHead``) and ``perspective`` from the test pipeline's rectification step."""
        steps = _steps(cfg, PERSPECTIVE_STEP)
        if not steps:
            raise ConfigError(
                f"{head.source}: the test pipeline has no {PERSPECTIVE_STEP} step: not a perspective-rectified "
                "fisheye configuration"
            )
        perspective = read_perspective(cfg, Section(steps[0], f"test_pipeline.{PERSPECTIVE_STEP}", head.source))
        return {
            "head": _pinhole_head(head, d.head, perspective.size, _backbone_of(cfg, head.source, d)),  # type: ignore[arg-type]
            "perspective": perspective,
        }
