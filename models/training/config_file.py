"""The mmdet3d-style config files ``fisheye-infer train`` writes beside a run's checkpoints, in the
official files' layout (``fisheye_bevdet.py``, ``fisheye_petr.py`` and the baselines' ``nusc_*.py``,
``fisheye_to_pinhole_*.py`` and ``fisheye_to_cyl_*.py``): what ``fisheye-infer export --config`` and the
configuration classes' ``from_mmdet3d_config`` read back.

Only the model and the test pipeline's steps that define the model's input are written. The
official files of the pinhole and rectified baselines and of FisheyePETR do not state the raw
camera size (it is the camera's); a file written here adds a top-level ``image_size = [H, W]``,
which mmdet3d ignores and the readers take.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..cyl_config import CYLINDER_STEP
from ..pinhole_views import IMAGE_AUG_STEP, PERSPECTIVE_STEP, RESIZE_CROP_STEP

__all__ = ["image_trunk_sections", "bevdet_config_source", "petr_config_source", "write_config"]

LOAD_STEP = "LoadFisheye3DODMultiViewImageFromFiles"


def image_trunk_sections(cfg: Any) -> dict[str, Any]:
    """The config sections every architecture shares: ``data_preprocessor``, ``img_backbone`` and ``img_neck``."""
    img, bb = cfg.image, cfg.backbone
    return dict(
        data_preprocessor=dict(mean=list(img.mean), std=list(img.std), bgr_to_rgb=img.bgr_to_rgb),
        img_backbone=dict(
            type="mmdet.ResNet",
            depth=bb.depth,
            base_channels=bb.base_channels,
            strides=list(bb.strides),
            dilations=list(bb.dilations),
            out_indices=list(bb.out_indices),
        ),
        img_neck=dict(
            type="mmdet.FPN",
            in_channels=list(bb.neck_in_channels),
            out_channels=bb.neck_out_channels,
            num_outs=bb.neck_num_outs,
        ),
    )


def bevdet_config_source(cfg: Any) -> str:
    """A ``BEVDetConfig`` (FisheyeBEVDet) or one of its baselines' (``PinholeBEVDetConfig``,
    ``PerspBEVDetConfig``, ``BEVDetCylConfig``) as an mmdet3d config file's source."""
    img, enc, hd = cfg.image, cfg.bev_encoder, cfg.head
    view_transform, steps = _bevdet_input(cfg)
    model = dict(
        type="FisheyeBEVDet" if view_transform["type"] == "FisheyeLSSTransform" else "BEVDet",
        **image_trunk_sections(cfg),
        view_transform=view_transform,
        pts_backbone=dict(
            type="SECOND",
            in_channels=enc.in_channels,
            out_channels=list(enc.out_channels),
            layer_nums=list(enc.layer_nums),
            layer_strides=list(enc.layer_strides),
            norm_cfg=dict(type="BN", eps=enc.bn_eps, momentum=0.01),
        ),
        pts_neck=dict(
            type="SECONDFPN",
            in_channels=list(enc.fpn_in_channels),
            out_channels=list(enc.fpn_out_channels),
            upsample_strides=list(enc.upsample_strides),
            use_conv_for_no_stride=enc.use_conv_for_no_stride,
            norm_cfg=dict(type="BN", eps=enc.bn_eps, momentum=0.01),
        ),
        bbox_head=dict(
            type="TransFusionHead",
            num_proposals=hd.num_proposals,
            in_channels=hd.in_channels,
            hidden_channel=hd.hidden_channel,
            num_classes=hd.num_classes,
            nms_kernel_size=hd.nms_kernel_size,
            num_decoder_layers=hd.num_decoder_layers,
            decoder_layer=dict(
                self_attn_cfg=dict(embed_dims=hd.hidden_channel, num_heads=hd.num_heads),
                ffn_cfg=dict(embed_dims=hd.hidden_channel, feedforward_channels=hd.ffn_channels),
            ),
            common_heads={name: list(spec) for name, spec in hd.common_heads},
            head_conv=hd.head_conv,
            bbox_coder=dict(
                type="TransFusionBBoxCoder",
                pc_range=list(hd.pc_range),
                post_center_range=list(hd.post_center_range),
                score_threshold=hd.score_threshold,
                out_size_factor=hd.out_size_factor,
                voxel_size=list(hd.voxel_size),
                code_size=8,
            ),
        ),
        test_cfg=dict(
            pts=dict(
                dataset=hd.dataset,
                grid_size=list(hd.grid_size),
                out_size_factor=hd.out_size_factor,
                voxel_size=list(hd.voxel_size),
                pc_range=list(hd.pc_range),
                nms_type=hd.nms_type,
            )
        ),
    )
    pipeline = [dict(type=LOAD_STEP, load_cam_names=list(img.camera_names)), *steps]
    return (
        f"# {type(cfg).__name__} written by fisheye-infer train (an mmdet3d-style config: read, never executed)\n"
        f"classes = {list(cfg.class_names)!r}\n"
        f"image_size = {[img.height, img.width]!r}\n"
        f"test_pipeline = {pipeline!r}\n"
        f"model = {model!r}\n"
    )


def _bevdet_input(cfg: Any) -> tuple[dict[str, Any], list[dict[str, Any]]]:
    """The view transform section of a BEVDet-family configuration and the test pipeline's steps after loading
    that make its input (resize and crop, perspective or cylindrical rectification)."""
    from fisheye_infer.models import BEVDetCylConfig, PerspBEVDetConfig, PinholeBEVDetConfig

    img, vt = cfg.image, cfg.view_transform
    common = dict(
        in_channels=vt.in_channels,
        out_channels=vt.out_channels,
        feature_size=list(vt.feature_size),
        xbound=list(vt.xbound),
        ybound=list(vt.ybound),
        zbound=list(vt.zbound),
        dbound=list(vt.dbound),
        downsample=1,
    )
    if isinstance(cfg, PinholeBEVDetConfig):
        h, w = vt.image_size
        image_aug = dict(type=IMAGE_AUG_STEP, **_resize_crop_fields(cfg, (h, w)), rot_lim=[0, 0], is_train=False)
        return dict(type="LSSTransform", image_size=[h, w], **common), [image_aug]
    if isinstance(cfg, PerspBEVDetConfig):
        h, w = vt.image_size
        return dict(type="LSSTransform", image_size=[h, w], **common), _perspective_steps(cfg.perspective)
    if isinstance(cfg, BEVDetCylConfig):
        size, ranges = cfg.cylinder, _cylinder_ranges(vt.azimuth_range, vt.elevation_range)
        view_transform = dict(type="CylindricalLSSTransform", image_size=[size.height, size.width], **common, **ranges)
        return view_transform, [_cylinder_step(size, ranges)]
    return dict(
        type="FisheyeLSSTransform",
        image_size=[img.height, img.width],
        azimuth_range=list(vt.azimuth_range),
        elevation_range=list(vt.elevation_range),
        ocam_fov=vt.ocam_fov,
        **common,
    ), []


def petr_config_source(cfg: Any) -> str:
    """A ``PETRConfig`` (FisheyePETR) or one of its baselines' (``PinholePETRConfig``, ``PerspPETRConfig``,
    ``CylPETRConfig``) as an mmdet3d config file's source."""
    img, bb, hd = cfg.image, cfg.backbone, cfg.head
    head_type, head_own, steps = _petr_input(cfg)
    layer_attn = dict(type="MultiheadAttention", embed_dims=hd.embed_dims, num_heads=hd.num_heads)
    model = dict(
        type="PETR",
        **image_trunk_sections(cfg),
        pts_bbox_head=dict(
            type=head_type,
            **head_own,
            num_classes=len(cfg.class_names),
            code_size=hd.code_size,
            in_channels=bb.neck_out_channels,
            num_query=hd.num_query,
            LID=hd.lid,
            depth_num=hd.depth_num,
            depth_start=hd.depth_start,
            position_range=list(hd.position_range),
            num_reg_fcs=hd.num_reg_fcs,
            transformer=dict(
                type="PETRTransformer",
                decoder=dict(
                    type="PETRTransformerDecoder",
                    return_intermediate=True,
                    num_layers=hd.num_layers,
                    transformerlayers=dict(
                        type="PETRTransformerDecoderLayer",
                        attn_cfgs=[layer_attn, {**layer_attn, "type": "PETRMultiheadAttention"}],
                        feedforward_channels=hd.ffn_dims,
                        operation_order=["self_attn", "norm", "cross_attn", "norm", "ffn", "norm"],
                    ),
                ),
            ),
            bbox_coder=dict(
                type="NMSFreeCoder",
                post_center_range=list(hd.post_center_range),
                pc_range=list(hd.point_cloud_range),
                max_num=hd.max_num,
                num_classes=len(cfg.class_names),
            ),
            positional_encoding=dict(
                type="SinePositionalEncoding3D",
                num_feats=hd.embed_dims // 2,
                normalize=True,
                temperature=hd.pe_temperature,
            ),
        ),
    )
    pipeline = [dict(type=LOAD_STEP, load_cam_names=list(img.camera_names)), *steps]
    return (
        f"# {type(cfg).__name__} written by fisheye-infer train (an mmdet3d-style config: read, never executed)\n"
        f"classes = {list(cfg.class_names)!r}\n"
        f"image_size = {[img.height, img.width]!r}\n"
        f"test_pipeline = {pipeline!r}\n"
        f"model = {model!r}\n"
    )


def _petr_input(cfg: Any) -> tuple[str, dict[str, Any], list[dict[str, Any]]]:
    """The head type of a PETR-family configuration, the head fields only that type has, and the test pipeline's
    steps after loading that make its input."""
    from fisheye_infer.models import CylPETRConfig, PerspPETRConfig, PinholePETRConfig

    hd = cfg.head
    if isinstance(cfg, PinholePETRConfig):
        conf = dict(_resize_crop_fields(cfg, hd.image_size), rot_lim=[0.0, 0.0], H=cfg.image.height, W=cfg.image.width)
        resize_crop = dict(type=RESIZE_CROP_STEP, data_aug_conf=conf, training=False)
        return "PETRHead", {}, [resize_crop]
    if isinstance(cfg, PerspPETRConfig):
        return "PETRHead", {}, _perspective_steps(cfg.perspective)
    if isinstance(cfg, CylPETRConfig):
        ranges = _cylinder_ranges(hd.azimuth_range, hd.elevation_range)
        return "CylindricalPETRHead", ranges, [_cylinder_step(cfg.cylinder, ranges)]
    spherical = dict(
        ocam_fov=hd.cam_fov,
        feature_size=list(hd.feature_size),
        dbound=list(hd.dbound),
        azimuth_range=list(hd.azimuth_range),
        elevation_range=list(hd.elevation_range),
    )
    return "FisheyePETRHead", spherical, []


# -- the test pipeline's steps that make a baseline's input ------------------------------------------


def _resize_crop_fields(cfg: Any, final: tuple[int, int]) -> dict[str, Any]:
    """The resize and test-mode crop of pinhole cameras (the fields ``ImageAug3D`` and ``ResizeCropFlipImage``
    share):
    ``bot_pct_lim`` is the official crop's, the share of resized rows below the crop."""
    from fisheye_infer.geometry.views import ResizeCrop

    img, aug, (h, w) = cfg.image, cfg.image_aug, final
    _, resized_h = ResizeCrop(scale=aug.scale).resized_size(img.width, img.height)
    bottom = (resized_h - aug.crop[1] - h) / resized_h
    return dict(final_dim=[h, w], resize_lim=[aug.scale, aug.scale], bot_pct_lim=[bottom, bottom], rand_flip=False)


def _perspective_steps(views: Any) -> list[dict[str, Any]]:
    """``MultiViewFisheyePerspectiveProjection`` of a ``PerspectiveConfig``, and the identity ``ImageAug3D`` whose
    uint8 cast truncates the views where the configuration says so."""
    h, w = views.size
    steps: list[dict[str, Any]] = [
        dict(
            type=PERSPECTIVE_STEP,
            image_size=[w, h],
            perspective_fov=views.fov,
            num_imgs_of_per_view=len(views.yaws),
            camera_orientation=list(views.yaws),
        )
    ]
    if views.truncate:
        steps.append(dict(type=IMAGE_AUG_STEP, final_dim=[h, w], resize_lim=[1, 1], bot_pct_lim=[0.0, 0.0]))
    return steps


def _cylinder_ranges(azimuth: tuple[float, float], elevation: tuple[float, float]) -> dict[str, list[float]]:
    return dict(horizontal_range=list(azimuth), vertical_range=list(elevation))


def _cylinder_step(size: Any, ranges: dict[str, list[float]]) -> dict[str, Any]:
    """``MultiViewFisheyeCylindricalProjection`` onto a ``CylinderConfig`` (the step writes (W, H))."""
    return dict(type=CYLINDER_STEP, image_size=[size.width, size.height], **ranges)


def write_config(cfg: Any, path: str | Path) -> Path:
    """Write ``cfg`` (a BEVDet-family or a ``PETRConfig``) as an mmdet3d config file to ``path`` and check that
    it reads back as ``cfg``."""
    from fisheye_infer.models import BEVDetConfig, PETRConfig

    path = Path(path)
    if isinstance(cfg, PETRConfig):
        path.write_text(petr_config_source(cfg))
    elif isinstance(cfg, BEVDetConfig):
        path.write_text(bevdet_config_source(cfg))
    else:
        raise TypeError(f"no config file format for {type(cfg).__name__}")
    back = type(cfg).from_mmdet3d_config(path)
    if back != cfg:
        raise RuntimeError(f"{path}: the written config does not read back as the configuration it describes")
    return path
