"""Configurations of the PETR pinhole baselines: ``nusc_petr.py`` and ``fisheye_to_pinhole_petr.py``.

PETR with the standard ``PETRHead``, on pinhole views; the two differ in where the views come
from, read from the official test pipeline (``pinhole_views``, shared with the BEVDet baselines
of ``pinhole_config``):

- pinhole cameras (``PinholePETRConfig``): six 1280x720 images, resized and cropped by the test
  pipeline's ``ResizeCropFlipImage`` (scale ``max(fH / H, fW / W)``);
- perspective views of fisheye cameras (``PerspPETRConfig``): four 800x800 images, each rectified
  into ``len(yaws)`` views by ``MultiViewFisheyePerspectiveProjection``; no ``ImageAug3D`` follows,
  so the float views are normalised as they are.

``image`` is the raw input the graph takes; ``head.image_size`` is the views' size.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

from fisheye_infer.cameras.rig import PINHOLE_CAMERAS
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.pinhole_petr import PinholePETRParams
from fisheye_infer.geometry.views import Perspective, ResizeCrop

from .config import ImageConfig, feature_size_of, read_backbone
from .mmconfig import Section
from .petr_config import PETRConfig, PETRHeadConfig, head_fields
from .pinhole_views import (
    PERSPECTIVE_STEP,
    RESIZE_CROP_STEP,
    ImageAugConfig,
    PerspectiveConfig,
    check_crop,
    check_views,
    pipeline_steps,
    range_mean,
    read_perspective,
    test_mode_crop,
)

__all__ = [
    "PinholePETRHeadConfig",
    "PinholePETRConfig",
    "PerspPETRConfig",
]


@dataclass(frozen=True)
class PinholePETRHeadConfig(PETRHeadConfig):
    """``PETRHead``: keys on the stride-16 features of each view; ``image_size`` (H, W) is the views' size (the
    padded input the key pixels are spread over: the released configs pad to a divisor of 1). The
    equirectangular fields of `PETRHeadConfig` play no part."""

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
        check_views("head", h.image_size, h.feature_size, h.image_size, self.backbone)
        check_crop(self.image, self.image_aug, h.image_size)

    def views(self) -> ResizeCrop:
        return self.image_aug.views()

    def geometry_params(self) -> Any:
        return _pinhole_petr_params(self, self.views())

    @classmethod
    def _read_head(cls, head: Section, cfg: Mapping[str, Any], d: PETRConfig) -> dict[str, Any]:
        """``head`` (a ``PETRHead``) and ``image_aug`` from the test pipeline's ``ResizeCropFlipImage``."""
        if pipeline_steps(cfg, PERSPECTIVE_STEP):
            raise ConfigError(
                f"{head.source}: the test pipeline rectifies fisheye images ({PERSPECTIVE_STEP}): a fisheye-petr-persp "
                "configuration, not a pinhole-camera one"
            )
        steps = pipeline_steps(cfg, RESIZE_CROP_STEP)
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
        cameras = cls._image_size(head, d, cfg)
        height, width = int(conf.get("H", cameras[0])), int(conf.get("W", cameras[1]))
        if (height, width) != cameras:
            raise ConfigError(
                f"{head.source}: {conf.where('H')}/{conf.where('W')}={height}x{width}: the pinhole cameras are "
                f"{cameras[0]}x{cameras[1]} (the file's image_size, else the official converter's size)"
            )
        aug = test_mode_crop(
            max(fh / height, fw / width), width, height, (fh, fw), range_mean(conf, "bot_pct_lim", (0.0, 0.0))
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
        check_views("head", h.image_size, h.feature_size, self.perspective.size, self.backbone)
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
        steps = pipeline_steps(cfg, PERSPECTIVE_STEP)
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
