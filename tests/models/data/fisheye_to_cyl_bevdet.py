# The test-time parts of configs/fisheye_to_cyl_bevdet.py (weiyangdaren/Fisheye3DOD @ 84a5bbd), as the
# reader sees them: the rectification step and the view transform both carry the ranges, written in
# degrees as in the released file.
_base_ = ['./default_runtime.py']

import math

classes = ['Car', 'Van', 'Truck', 'Bus', 'Pedestrian', 'Cyclist']
ref_range = 48
cam_type = 'cam_fisheye'
cam_names = ['fisheye_camera_front', 'fisheye_camera_left', 'fisheye_camera_right', 'fisheye_camera_rear']
xbound = [-ref_range, ref_range, 0.3]
ybound = [-ref_range, ref_range, 0.3]
zbound = [-5.0, 5.0, 10.0]
dbound = [0.5, ref_range + 0.5, 0.5]

test_pipeline = [
    dict(type='LoadFisheye3DODMultiViewImageFromFiles', to_float32=True, color_type='color',
         load_cam_type=cam_type, load_cam_names=cam_names),
    dict(type='MultiViewFisheyeCylindricalProjection', image_size=(800, 400),  # (W, H)
         horizontal_range=[-110, 110], vertical_range=[-45, 45]),
    dict(type='Fisheye3DODPackDetInputs', keys=[cam_type], input_img_keys=[cam_type]),
]

model = dict(
    type='BEVDet',
    data_preprocessor=dict(type='FisheyeDet3DDataPreprocessor', mean=[123.675, 116.28, 103.53],
                           std=[58.395, 57.12, 57.375], bgr_to_rgb=False, img_keys=[cam_type]),
    img_backbone=dict(type='mmdet.ResNet', depth=18, in_channels=3, base_channels=64, num_stages=4,
                      strides=(1, 2, 2, 2), dilations=(1, 1, 2, 4), out_indices=(2, 3)),
    img_neck=dict(type='mmdet.FPN', in_channels=[256, 512], out_channels=256, num_outs=2),
    view_transform=dict(
        type='CylindricalLSSTransform', in_channels=256, out_channels=96,
        image_size=[400, 800],  # (H, W)
        feature_size=[25, 50], xbound=xbound, ybound=ybound, zbound=zbound, dbound=dbound, downsample=1,
        horizontal_range=[-110, 110], vertical_range=[-45, 45]),
    pts_backbone=dict(type='SECOND', in_channels=96, out_channels=[128, 256], layer_nums=[5, 5],
                      layer_strides=[2, 2], norm_cfg=dict(type='BN', eps=0.001, momentum=0.01),
                      conv_cfg=dict(type='Conv2d', bias=False)),
    pts_neck=dict(type='SECONDFPN', in_channels=[128, 256], out_channels=[256, 256], upsample_strides=[1, 2],
                  norm_cfg=dict(type='BN', eps=0.001, momentum=0.01),
                  upsample_cfg=dict(type='deconv', bias=False), use_conv_for_no_stride=True),
    bbox_head=dict(
        type='TransFusionHead', num_proposals=200, auxiliary=True, in_channels=512, hidden_channel=128,
        num_classes=6, nms_kernel_size=3, num_decoder_layers=1,
        decoder_layer=dict(
            type='TransFusionTransformerDecoderLayer',
            self_attn_cfg=dict(embed_dims=128, num_heads=8, dropout=0.1),
            cross_attn_cfg=dict(embed_dims=128, num_heads=8, dropout=0.1),
            ffn_cfg=dict(embed_dims=128, feedforward_channels=256, num_fcs=2, ffn_drop=0.1)),
        common_heads=dict(center=[2, 2], height=[1, 2], dim=[3, 2], rot=[2, 2]),
        bbox_coder=dict(type='TransFusionBBoxCoder', pc_range=[-48.0, -48.0],
                        post_center_range=[-50, -50, -5.0, 50, 50, 5.0], score_threshold=0.0,
                        out_size_factor=8, voxel_size=[0.075, 0.075], code_size=8)),
    test_cfg=dict(pts=dict(dataset='Fisheye3DOD', grid_size=[1280, 1280, 40], out_size_factor=8,
                           voxel_size=[0.075, 0.075], pc_range=[-48.0, -48.0], nms_type=None)),
)
