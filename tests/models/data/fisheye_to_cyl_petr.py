# The test-time parts of configs/fisheye_to_cyl_petr.py (weiyangdaren/Fisheye3DOD @ 84a5bbd), as the
# reader sees them: the rectification step and CylindricalPETRHead both carry the ranges, written in
# degrees as in the released file.
_base_ = ["./default_runtime.py"]

classes = ["Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist"]
ref_range = 48
detect_range = [-ref_range, -ref_range, -5, ref_range, ref_range, 5]
cam_type = "cam_fisheye"

test_pipeline = [
    dict(type="LoadFisheye3DODMultiViewImageFromFiles", to_float32=True, color_type="color", load_cam_type=cam_type,
         load_cam_names=["fisheye_camera_front", "fisheye_camera_left", "fisheye_camera_right", "fisheye_camera_rear"]),
    dict(type="MultiViewFisheyeCylindricalProjection", image_size=(800, 400),  # (W, H)
         horizontal_range=[-110, 110], vertical_range=[-45, 45]),
    dict(type="Fisheye3DODPackDetInputs", keys=[cam_type], input_img_keys=[cam_type]),
]

import math

model = dict(
    type="PETR",
    data_preprocessor=dict(type="FisheyeDet3DDataPreprocessor", mean=[123.675, 116.28, 103.53],
                           std=[58.395, 57.12, 57.375], bgr_to_rgb=False, img_keys=[cam_type]),
    img_backbone=dict(type="mmdet.ResNet", depth=18, in_channels=3, base_channels=64, num_stages=4,
                      strides=(1, 2, 2, 2), dilations=(1, 1, 2, 4), out_indices=(2, 3)),
    img_neck=dict(type="mmdet.FPN", in_channels=[256, 512], out_channels=256, num_outs=2),
    pts_bbox_head=dict(
        type="CylindricalPETRHead", horizontal_range=(-110, 110), vertical_range=(-45, 45),
        num_classes=6, code_size=8, in_channels=256, num_query=900, LID=True, with_position=True,
        with_multiview=True, depth_start=0.5, position_range=[-60, -60, -10.0, 60, 60, 10.0],
        transformer=dict(type="PETRTransformer", decoder=dict(
            type="PETRTransformerDecoder", return_intermediate=True, num_layers=6,
            transformerlayers=dict(
                type="PETRTransformerDecoderLayer",
                attn_cfgs=[dict(type="MultiheadAttention", embed_dims=256, num_heads=8),
                           dict(type="PETRMultiheadAttention", embed_dims=256, num_heads=8)],
                feedforward_channels=2048, ffn_dropout=0.1,
                operation_order=("self_attn", "norm", "cross_attn", "norm", "ffn", "norm")))),
        bbox_coder=dict(type="NMSFreeCoder", post_center_range=[-60, -60, -10.0, 60, 60, 10.0],
                        pc_range=detect_range, max_num=300, num_classes=6),
        positional_encoding=dict(type="SinePositionalEncoding3D", num_feats=128, normalize=True)),
)
