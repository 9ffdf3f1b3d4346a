"""Pure numpy geometry tables: arrays in, arrays out, float64 inside, float32 out.

One source of truth for the sampling grids, frustums, BEV pooling plans and PETR position
coordinates that the PyTorch models, the exporter and the runtime share.
"""

from fisheye_infer.geometry.frustum import cylindrical_frustum, depth_bins, frustum_to_lidar, linspace_depth_bins, spherical_frustum
from fisheye_infer.geometry.grids import (
    cylindrical_grid,
    cylindrical_image_grid,
    cylindrical_remap,
    invalid_mask,
    remap_grid,
    sample_bilinear,
    spherical_directions,
    spherical_grid,
)
from fisheye_infer.geometry.petr import lid_depths, position_coords
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan, pool_bev, pool_bev_reference

__all__ = [
    "BevGrid",
    "PoolingPlan",
    "build_pooling_plan",
    "cylindrical_frustum",
    "cylindrical_grid",
    "cylindrical_image_grid",
    "cylindrical_remap",
    "depth_bins",
    "frustum_to_lidar",
    "invalid_mask",
    "lid_depths",
    "linspace_depth_bins",
    "pool_bev",
    "pool_bev_reference",
    "position_coords",
    "remap_grid",
    "sample_bilinear",
    "spherical_directions",
    "spherical_frustum",
    "spherical_grid",
]
