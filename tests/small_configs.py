"""Reduced detector configurations shared by the tests: every stage of the official graph at a
fraction of the cost. They go with the shipped rig resized by 0.2 (160 x 160 images)."""

from __future__ import annotations

#: BEV-side sections (view transform, BEV encoder, TransFusion head) of a reduced FisheyeBEVDet:
#: 24 depth bins, a 48 m BEV square of 80x80 cells, narrower encoder and head.
SMALL_BEV_SECTIONS = {
    "view_transform": {"out_channels": 32, "xbound": (-24.0, 24.0, 0.6), "ybound": (-24.0, 24.0, 0.6), "dbound": (0.5, 24.5, 1.0)},
    "bev_encoder": {"in_channels": 32, "out_channels": (32, 64), "layer_nums": (1, 1), "fpn_in_channels": (32, 64), "fpn_out_channels": (32, 32)},
    "head": {"in_channels": 64, "hidden_channel": 32, "num_heads": 4, "ffn_channels": 64, "head_conv": 16, "num_proposals": 50,
             "grid_size": (320, 320, 40), "pc_range": (-24.0, -24.0), "voxel_size": (0.15, 0.15),
             "post_center_range": (-26.0, -26.0, -5.0, 26.0, 26.0, 5.0)},
}


def small_bevdet_config():
    """Four 160x160 cameras and an 8x32 angular grid."""
    from fisheye_infer.models import BEVDetConfig

    sections = dict(SMALL_BEV_SECTIONS, view_transform={**SMALL_BEV_SECTIONS["view_transform"], "feature_size": (8, 32)})
    return BEVDetConfig().replace(image={"height": 160, "width": 160}, **sections)
