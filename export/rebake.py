"""``rebake``: recompute an exported file's geometry for a new rig, with numpy and onnx only.

    rebake("model.onnx", "new_rig.yaml", "model_new_rig.onnx")

The metadata of an exported file records the parameters of its geometry tables (and, for
FisheyePETR, the position-encoder weights the key embedding needs), so every ``geom.*``
initializer can be recomputed without torch. The graph itself is unchanged: it was traced with
the pooling tables' sizes symbolic; every other table keeps its shape (a file whose tables this
version computes in another shape is refused, naming the table). The TensorRT check is run again
on the new file (the tables' sizes are part of what it reads). The input file is never modified.
A rig whose camera names, order or image size do not fit the graph is refused.
"""

from __future__ import annotations

from pathlib import Path

import onnx

from fisheye_infer.cameras.rig import Rig, resolve_rig
from fisheye_infer.errors import ArtifactError, ConfigError, RigError
from fisheye_infer.geometry.kinds import tables_for
from fisheye_infer.geometry.tables import POOL_PIXELS, POOL_POINTS
from fisheye_infer.runtime.artifact import METADATA_KEY, ArtifactMeta, parse_meta

from .graph import REBAKE_WEIGHTS_KEY, decode_arrays, get_metadata, replace_initializers, save_model, set_metadata
from .tensorrt_check import check_tensorrt

__all__ = ["rebake"]


def rebake(model_path: str | Path, rig: str | Path | Rig, out: str | Path) -> ArtifactMeta:
    """Write ``out``: ``model_path`` with every geometry table recomputed for ``rig``; returns its metadata."""
    model_path, out = Path(model_path), Path(out)
    if out.resolve() == model_path.resolve():
        raise ArtifactError(f"--out {out}: re-baking never overwrites its input; choose another path")
    try:
        proto = onnx.load(str(model_path))
    except Exception as exc:
        raise ArtifactError(f"model {model_path}: cannot be read as ONNX ({exc})") from exc
    props = get_metadata(proto)
    meta = parse_meta(props.get(METADATA_KEY), source=f"model {model_path}")
    new_rig = rig if isinstance(rig, Rig) else resolve_rig(rig)
    if len(new_rig) != len(meta.cameras):
        raise RigError(
            f"the rig has {len(new_rig)} cameras, the model was built for {len(meta.cameras)} "
            f"({', '.join(meta.cameras)})"
        )
    new_rig.require(meta.cameras, meta.image_size)
    weights = decode_arrays(props[REBAKE_WEIGHTS_KEY]) if REBAKE_WEIGHTS_KEY in props else None
    try:
        tables = tables_for(new_rig, meta.geometry, weights)
    except ConfigError as exc:  # e.g. a PETR file without the weights its key embedding needs
        raise ArtifactError(f"model {model_path}: {exc}") from None
    if set(tables) != set(meta.geometry_initializers):
        raise ArtifactError(
            f"model {model_path}: its geometry initializers {sorted(meta.geometry_initializers)} differ from those "
            f"its parameters define {sorted(tables)}"
        )
    held = {init.name: tuple(init.dims) for init in proto.graph.initializer if init.name in tables}
    for name, table in tables.items():
        if name in held and not name.startswith((POOL_POINTS, POOL_PIXELS)) and held[name] != table.shape:
            raise ArtifactError(
                f"model {model_path}: its geometry table {name} is {held[name]}, where this version computes "
                f"{table.shape} for the rig; the file comes from another version of the exporter: export the "
                "checkpoint again"
            )
    replace_initializers(proto, tables)
    model_id = f"{meta.architecture}-{new_rig.hash[:8]}-{(meta.checkpoint_sha256 or 'unknown')[:8]}"
    new_meta = meta.model_copy(
        update={
            "rig": new_rig,
            "rig_hash": new_rig.hash,
            "model_id": model_id,
            "geometry_source": "rig",
            "parity": None,
            "tensorrt": check_tensorrt(proto),
        }
    )  # its notes quote table values, which the rig changes
    set_metadata(proto, new_meta.check())
    save_model(proto, out)
    return new_meta
