"""Pure numpy geometry: arrays in, arrays out, float64 inside, float32 out.

One source of truth for the sampling grids and their bilinear taps, frustums, BEV pooling plans and PETR position
coordinates that the PyTorch models, the exporter and the runtime share. The building blocks are
``grids``, ``frustum``, ``pooling``, the coordinate functions of ``petr``, the pinhole ``views`` of
the baselines and PIL's ``resize``; one module per parameter kind (``lss``, ``cyl_lss``, ``petr``,
``cyl_petr``, ``pinhole_lss``, ``pinhole_petr``) turns a rig into a geometry object, whose
``tables()`` are the ``geom.*`` tables named and laid out in ``tables``; ``kinds`` picks the
geometry object of a parameter kind.
"""

from fisheye_infer.geometry.cyl_lss import CylLSSGeometry, CylLSSParams
from fisheye_infer.geometry.cyl_petr import CylPETRGeometry, CylPETRParams
from fisheye_infer.geometry.frustum import (
    cylindrical_frustum,
    depth_bins,
    frustum_to_lidar,
    linspace_depth_bins,
    spherical_frustum,
)
from fisheye_infer.geometry.grids import (
    BilinearTaps,
    bilinear_taps,
    cells_inside_lens,
    cylindrical_grid,
    cylindrical_image_grid,
    cylindrical_remap,
    invalid_mask,
    remap_grid,
    sample_bilinear,
    spherical_directions,
    spherical_grid,
)
from fisheye_infer.geometry.kinds import Geometry, GeometryParams, geometry_from_rig, tables_for
from fisheye_infer.geometry.lss import LSSGeometry, LSSParams
from fisheye_infer.geometry.petr import PETRGeometry, PETRParams, lid_depths, position_coords
from fisheye_infer.geometry.pinhole_lss import PinholeLSSGeometry, PinholeLSSParams
from fisheye_infer.geometry.pinhole_petr import PinholePETRGeometry, PinholePETRParams
from fisheye_infer.geometry.pooling import BevGrid, PoolingPlan, build_pooling_plan, pool_bev, pool_bev_reference

__all__ = [
    "BevGrid",
    "BilinearTaps",
    "bilinear_taps",
    "CylLSSGeometry",
    "CylLSSParams",
    "CylPETRGeometry",
    "CylPETRParams",
    "Geometry",
    "GeometryParams",
    "LSSGeometry",
    "LSSParams",
    "PETRGeometry",
    "PETRParams",
    "PinholeLSSGeometry",
    "PinholeLSSParams",
    "PinholePETRGeometry",
    "PinholePETRParams",
    "PoolingPlan",
    "build_pooling_plan",
    "cells_inside_lens",
    "cylindrical_frustum",
    "cylindrical_grid",
    "cylindrical_image_grid",
    "cylindrical_remap",
    "depth_bins",
    "frustum_to_lidar",
    "geometry_from_rig",
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
    "tables_for",
]
