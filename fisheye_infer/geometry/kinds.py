"""The parameter kinds and their geometry objects: the one path from a rig to the tables.

    geometry = geometry_from_rig(rig, params)      # one geometry class per parameter kind
    tables = tables_for(rig, params, weights)      # what the model holds and re-baking writes

The PyTorch models build their geometry here and turn ``geometry.tables(...)`` into buffers;
the exporter bakes the same tables, and ``rebake`` recomputes them for another rig.
"""

from __future__ import annotations

import numpy as np

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.errors import ConfigError
from fisheye_infer.geometry.cyl_lss import CylLSSGeometry, CylLSSParams
from fisheye_infer.geometry.cyl_petr import CylPETRGeometry, CylPETRParams
from fisheye_infer.geometry.lss import LSSGeometry, LSSParams
from fisheye_infer.geometry.petr import PETRGeometry, PETRParams
from fisheye_infer.geometry.pinhole_lss import PinholeLSSGeometry, PinholeLSSParams
from fisheye_infer.geometry.pinhole_petr import PinholePETRGeometry, PinholePETRParams

__all__ = ["GeometryParams", "Geometry", "GEOMETRY_KINDS", "geometry_from_rig", "tables_for"]

GeometryParams = LSSParams | PETRParams | CylLSSParams | CylPETRParams | PinholeLSSParams | PinholePETRParams
Geometry = LSSGeometry | PETRGeometry | CylLSSGeometry | CylPETRGeometry | PinholeLSSGeometry | PinholePETRGeometry

#: parameter kind -> its geometry class
GEOMETRY_KINDS: dict[str, type[Geometry]] = {
    "lss": LSSGeometry,
    "petr": PETRGeometry,
    "cyl_lss": CylLSSGeometry,
    "cyl_petr": CylPETRGeometry,
    "pinhole_lss": PinholeLSSGeometry,
    "pinhole_petr": PinholePETRGeometry,
}


def geometry_from_rig(rig: Rig, params: GeometryParams) -> Geometry:
    """The geometry object of ``params``' kind for ``rig``.

    Args:
        rig: The cameras the tables are computed for.
        params: The geometry parameters a model's metadata carries (their ``kind`` picks the geometry).

    Returns:
        Geometry: The geometry object; its ``tables()`` are the file's ``geom.*`` tables.

    Raises:
        ConfigError: No geometry is known for the parameters' kind.
    """
    kind = getattr(params, "kind", type(params).__name__)
    if kind not in GEOMETRY_KINDS:
        raise ConfigError(f"geometry: no tables for parameters of kind {kind!r} (known: {', '.join(GEOMETRY_KINDS)})")
    return GEOMETRY_KINDS[kind].from_rig(rig, params)  # type: ignore[arg-type]


def tables_for(rig: Rig, params: GeometryParams, weights: dict[str, np.ndarray] | None = None) -> dict[str, np.ndarray]:
    """The ``geom.*`` tables of a graph described by ``params``, for ``rig`` (what re-baking computes).

    Args:
        rig: The cameras the tables are computed for.
        params: The geometry parameters of the file's metadata.
        weights: The position-encoder weights the PETR kinds need (``geom.petr.key_pos``); None for the others.

    Returns:
        dict[str, numpy.ndarray]: Each table by its initializer name.

    Raises:
        ConfigError: The kind is unknown, or a PETR kind lacks a weight it needs.

    Examples:
        ```python
        from fisheye_infer.geometry import tables_for
        from fisheye_infer.runtime.artifact import read_meta

        meta = read_meta("model.onnx")  # a FisheyeBEVDet file
        tables = tables_for(meta.rig, meta.geometry)  # the tables it holds
        print(tables["geom.warp.weight"].shape)
        ```
    """
    return geometry_from_rig(rig, params).tables(weights)
