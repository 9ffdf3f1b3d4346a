"""A FisheyePETR configuration as an official-style mmdet3d config file (what ``PETRConfig.from_mmdet3d_config`` reads).

The official ``fisheye_petr.py`` does not state the image size (it is the OCam calibration's);
a file written here adds a top-level ``image_size = [H, W]``, which mmdet3d ignores and the
reader takes.
"""

from __future__ import annotations

from typing import Any

from .compact import image_trunk_sections

__all__ = ["petr_config_source"]


def petr_config_source(cfg: Any) -> str:
    """A ``PETRConfig`` as an mmdet3d config file's source."""
    img, bb, hd = cfg.image, cfg.backbone, cfg.head
    layer_attn = dict(type="MultiheadAttention", embed_dims=hd.embed_dims, num_heads=hd.num_heads)
    model = dict(
        type="PETR",
        **image_trunk_sections(cfg),
        pts_bbox_head=dict(
            type="FisheyePETRHead",
            num_classes=len(cfg.class_names),
            code_size=hd.code_size,
            in_channels=bb.neck_out_channels,
            num_query=hd.num_query,
            LID=hd.lid,
            depth_num=hd.depth_num,
            depth_start=hd.depth_start,
            position_range=list(hd.position_range),
            num_reg_fcs=hd.num_reg_fcs,
            ocam_fov=hd.cam_fov,
            feature_size=list(hd.feature_size),
            dbound=list(hd.dbound),
            azimuth_range=list(hd.azimuth_range),
            elevation_range=list(hd.elevation_range),
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
    pipeline = [dict(type="LoadFisheye3DODMultiViewImageFromFiles", load_cam_names=list(img.camera_names))]
    return (
        "# FisheyePETR configuration written by fisheye-infer train (an mmdet3d-style config: read, never executed)\n"
        f"classes = {list(cfg.class_names)!r}\n"
        f"image_size = {[img.height, img.width]!r}\n"
        f"test_pipeline = {pipeline!r}\n"
        f"model = {model!r}\n"
    )
