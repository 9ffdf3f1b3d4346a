"""The compact FisheyeBEVDet and FisheyePETR that train on a CPU, and the mmdet3d-style config files that
describe them.

Same architecture as the official ``fisheye_bevdet.py`` (ResNet-18 + FPN, fisheye LSS, SECOND +
SECONDFPN, TransFusion head) with sizes cut where the measured cost of a training step says so
(README, "Training"): four 320 x 320 cameras (the shipped rig resized by 0.4, so the backbone sees
0.16 of the official pixels), ResNet-18 at half width (``base_channels=32``, which also keeps the
checkpoint under 15 MB), a 10 x 40 angular grid, 48 one-metre depth bins, the official 96 m BEV
square at 0.6 m cells (160 x 160, 80 x 80 at the head), narrower neck, BEV encoder and head, and
100 proposals. The compact FisheyePETR has the same rig and image backbone (so it can start from
the compact FisheyeBEVDet's, ``--init-backbone``), the same 10 x 40 angular key grid, and a
decoder of the official depth (6 layers) at half width (128 channels, 4 heads, 512 in the FFN)
with 300 queries. The official full-size configurations stay the default everywhere else.

A trained checkpoint is exported like any other by passing the config file this module writes:

    fisheye-infer export --ckpt runs/compact/model.pth --config runs/compact/config.py \\
        --rig runs/compact/rig.json --out model.onnx
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.scenes.render import resized_rig

__all__ = [
    "COMPACT_SCALE",
    "COMPACT_SECTIONS",
    "COMPACT_PETR_SECTIONS",
    "compact_bevdet_config",
    "compact_petr_config",
    "compact_rig",
    "image_trunk_sections",
    "mmdet3d_config_source",
    "write_config",
]

#: Image scale of the compact model's rig (800 x 800 -> 320 x 320).
COMPACT_SCALE = 0.4
COMPACT_SECTIONS: dict[str, dict[str, Any]] = {
    "image": {"height": 320, "width": 320},
    "backbone": {"base_channels": 32, "neck_in_channels": (128, 256), "neck_out_channels": 64},
    "view_transform": {
        "in_channels": 64,
        "out_channels": 48,
        "feature_size": (10, 40),
        "dbound": (0.5, 48.5, 1.0),
        "xbound": (-48.0, 48.0, 0.6),
        "ybound": (-48.0, 48.0, 0.6),
    },
    "bev_encoder": {
        "in_channels": 48,
        "out_channels": (64, 128),
        "layer_nums": (2, 2),
        "fpn_in_channels": (64, 128),
        "fpn_out_channels": (64, 64),
    },
    "head": {
        "in_channels": 128,
        "hidden_channel": 64,
        "num_heads": 4,
        "ffn_channels": 128,
        "head_conv": 32,
        "num_proposals": 100,
        "grid_size": (640, 640, 40),
        "voxel_size": (0.15, 0.15),
    },
}


COMPACT_PETR_SECTIONS: dict[str, dict[str, Any]] = {
    "image": COMPACT_SECTIONS["image"],
    "backbone": COMPACT_SECTIONS["backbone"],
    "head": {
        "feature_size": (10, 40),
        "dbound": (0.5, 48.5, 1.0),
        "embed_dims": 128,
        "num_heads": 4,
        "ffn_dims": 512,
        "num_query": 300,
    },
}


def compact_petr_config() -> Any:
    """The compact FisheyePETR configuration (a ``PETRConfig``)."""
    from fisheye_infer.models import PETRConfig

    return PETRConfig().replace(**COMPACT_PETR_SECTIONS)


def compact_bevdet_config() -> Any:
    """The compact configuration (a ``BEVDetConfig``)."""
    from fisheye_infer.models import BEVDetConfig

    return BEVDetConfig().replace(**COMPACT_SECTIONS)


def compact_rig(rig: Rig | None = None) -> Rig:
    """The rig the compact model sees: ``rig`` (default: the shipped one) with its images scaled by
    ``COMPACT_SCALE``."""
    return resized_rig(rig or default_rig(), COMPACT_SCALE)


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


def mmdet3d_config_source(cfg: Any) -> str:
    """A ``BEVDetConfig`` as an official-style mmdet3d config file (what
    ``BEVDetConfig.from_mmdet3d_config`` reads back)."""
    img, vt, enc, hd = cfg.image, cfg.view_transform, cfg.bev_encoder, cfg.head
    model = dict(
        type="FisheyeBEVDet",
        **image_trunk_sections(cfg),
        view_transform=dict(
            type="FisheyeLSSTransform",
            in_channels=vt.in_channels,
            out_channels=vt.out_channels,
            image_size=[img.height, img.width],
            feature_size=list(vt.feature_size),
            azimuth_range=list(vt.azimuth_range),
            elevation_range=list(vt.elevation_range),
            xbound=list(vt.xbound),
            ybound=list(vt.ybound),
            zbound=list(vt.zbound),
            dbound=list(vt.dbound),
            ocam_fov=vt.ocam_fov,
            downsample=1,
        ),
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
    pipeline = [dict(type="LoadFisheye3DODMultiViewImageFromFiles", load_cam_names=list(img.camera_names))]
    return (
        "# FisheyeBEVDet configuration written by fisheye-infer train (an mmdet3d-style config: read, never executed)\n"
        f"classes = {list(cfg.class_names)!r}\n"
        f"test_pipeline = {pipeline!r}\n"
        f"model = {model!r}\n"
    )


def write_config(cfg: Any, path: str | Path) -> Path:
    """Write ``cfg`` (a ``BEVDetConfig`` or ``PETRConfig``) as an mmdet3d config file to ``path`` and check that
    it reads back as ``cfg``."""
    from fisheye_infer.models import BEVDetConfig, PETRConfig

    from .petr_config_file import petr_config_source

    path = Path(path)
    if type(cfg) is PETRConfig:
        path.write_text(petr_config_source(cfg))
    elif type(cfg) is BEVDetConfig:
        path.write_text(mmdet3d_config_source(cfg))
    else:
        raise TypeError(f"no config file format for {type(cfg).__name__}")
    back = type(cfg).from_mmdet3d_config(path)
    if back != cfg:
        raise RuntimeError(f"{path}: the written config does not read back as the configuration it describes")
    return path
