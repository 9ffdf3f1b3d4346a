"""``rebake``: an exported file for another rig, with numpy and onnx only.

    rebake("model.onnx", "robot_rig.yaml", "model_robot.onnx")                  # virtual cameras (the default)
    rebake("model.onnx", "recalibrated.yaml", "model_new.onnx", mode="tables")  # new tables, no resampling

``virtual`` (the default for a rig that is not the file's training rig): the file takes the robot's raw images, each
camera at its own size, and a front end in the graph resamples each into the image its training camera would have
taken (``fisheye_infer.geometry.virtual``, ``virtual_front``); the network and its geometry tables stay as trained,
but for FisheyePETR's key mask and embedding, which also mask the keys that read pixels the robot cameras do not see.
Robot cameras are mapped onto the model's by ``camera_map`` or by heading
(``fisheye_infer.cameras.camera_map.map_cameras``).

``tables``: every ``geom.*`` initializer recomputed for the rig. The metadata of an exported file records the
parameters of its geometry tables (and, for FisheyePETR, the position-encoder weights the key embedding needs), so
the tables can be recomputed without torch. The graph itself is unchanged: it was traced with the pooling tables'
sizes symbolic; every other table keeps its shape (a file whose tables this version computes in another shape is
refused, naming the table). A rig whose camera names, order or image size do not fit the graph is refused. The
network then sees pictures through the new lenses and mounts, which it was not trained on. A file whose tables came
from its checkpoint (``geometry_source``), re-baked onto its training rig, keeps them.

The TensorRT check is run again on the new file. The input file is never modified.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Literal

import numpy as np
import onnx

from fisheye_infer.cameras.camera_map import map_cameras
from fisheye_infer.cameras.rig import Rig, resolve_rig
from fisheye_infer.cameras.virtual_view import UNSEEN_FILL
from fisheye_infer.errors import ArtifactError, ConfigError, RigError
from fisheye_infer.geometry.kinds import geometry_from_rig, tables_for
from fisheye_infer.geometry.petr import PETRGeometry, remasked_key_embedding
from fisheye_infer.geometry.tables import PETR_KEY_MASK, PETR_KEY_POS, POOL_PIXELS, POOL_POINTS, key_tables
from fisheye_infer.geometry.virtual import virtual_front
from fisheye_infer.runtime.artifact import METADATA_KEY, ArtifactMeta, VirtualCameras, parse_meta

from .graph import (
    REBAKE_WEIGHTS_KEY,
    TRAINED_KEY_MASK_KEY,
    decode_arrays,
    encode_arrays,
    get_metadata,
    initializer_arrays,
    replace_initializers,
    save_model,
    set_metadata,
)
from .tensorrt_check import check_tensorrt
from .virtual_front import attach_front, detach_front, has_front

__all__ = ["RebakeMode", "rebake"]

RebakeMode = Literal["auto", "virtual", "tables"]


def rebake(
    model_path: str | Path,
    rig: str | Path | Rig,
    out: str | Path,
    *,
    mode: RebakeMode = "auto",
    camera_map: Mapping[str, str] | None = None,
    depth: float | None = None,
) -> ArtifactMeta:
    """Write an exported file for the cameras of another rig, with numpy and onnx only (no torch).

    ``virtual`` mode: the new file takes the rig's raw images, each camera at its own size, and a front end in the
    graph resamples each into the image its training camera would have taken; the network and its geometry tables
    stay as trained (FisheyePETR's key mask also hides the pixels the new cameras do not see). ``tables`` mode:
    every ``geom.*`` initializer is recomputed for the rig from the parameters the metadata records (a checkpoint's
    own tables are kept on the training rig); the network then sees pictures through lenses and mounts it was not
    trained on. The TensorRT check is run again on the new file; the input file is never modified.

    Args:
        model_path (str | Path): A file written by ``fisheye-infer export`` (or by ``rebake``).
        rig (str | Path | Rig): The new rig: a rig file, a folder, ``default``, or a ``Rig``.
        out (str | Path): Where to write the new file (never ``model_path``).
        mode (str): ``virtual``: a front end resamples the rig's cameras into the training cameras; ``tables``: the
            geometry tables are recomputed for the rig (same camera names, order and image size); ``auto``:
            ``tables`` for the file's training rig itself, ``virtual`` otherwise.
        camera_map (Mapping[str, str] | None): ``virtual`` only: the model's camera name -> the rig's camera name
            for every camera; None maps them by heading.
        depth (float | None): ``virtual`` only: None compensates rotation only; a distance in metres compensates
            the cameras' offsets at that distance.

    Returns:
        ArtifactMeta: The new file's metadata
            ([`ArtifactMeta`][fisheye_infer.runtime.artifact.ArtifactMeta]).

    Raises:
        ArtifactError: The input cannot be read, is the output, or its tables do not fit this version.
        RigError: The rig cannot be read or does not fit (camera names or sizes in ``tables`` mode; the camera map
            in ``virtual``), or ``camera_map`` is given with ``mode="tables"``.

    Examples:
        ```python
        from fisheye_infer.export.rebake import rebake

        meta = rebake("model.onnx", "robot_rig.yaml", "model_robot.onnx")  # virtual cameras
        rebake("model.onnx", "recalibrated.yaml", "model_new.onnx", mode="tables")  # new tables, no resampling
        print(meta.model_id, meta.cameras, meta.tensorrt.compatible)
        ```
    """
    model_path, out = Path(model_path), Path(out)
    if out.resolve() == model_path.resolve():
        raise ArtifactError(f"--out {out}: re-baking never overwrites its input; choose another path")
    if camera_map is not None and mode == "tables":
        raise RigError("camera map: the tables mode keeps the model's camera names; a map is for virtual cameras")
    if not model_path.is_file():
        raise ArtifactError(f"model {model_path}: no such file (a regular ONNX file written by fisheye-infer export)")
    try:
        proto = onnx.load(str(model_path))
    except Exception as exc:
        raise ArtifactError(f"model {model_path}: cannot be read as ONNX ({exc})") from exc
    props = get_metadata(proto)
    meta = parse_meta(props.get(METADATA_KEY), source=f"model {model_path}")
    new_rig = rig if isinstance(rig, Rig) else resolve_rig(rig)
    training = meta.training_rig
    if mode == "auto":
        mode = "tables" if new_rig.hash == training.hash and camera_map is None else "virtual"
    if mode == "virtual":
        new_meta, extra = _virtual(proto, props, meta, new_rig, camera_map, depth)
    else:
        new_meta, extra = _tables(proto, props, meta, new_rig, model_path)
    final = new_meta.model_copy(update={"tensorrt": check_tensorrt(proto)}).check()
    for stale in [p for p in proto.metadata_props if p.key == TRAINED_KEY_MASK_KEY and p.key not in extra]:
        proto.metadata_props.remove(stale)  # tables recomputed for a rig: their own mask is the one to raise
    set_metadata(proto, final, extra)
    save_model(proto, out)
    return final


def _on_rig(meta: ArtifactMeta, rig: Rig, image_size: tuple[int, int], **update: object) -> ArtifactMeta:
    """``meta`` for a file that takes ``rig``'s cameras at ``image_size``, with the other fields of ``update``."""
    model_id = f"{meta.architecture}-{rig.hash[:8]}-{(meta.checkpoint_sha256 or 'unknown')[:8]}"
    fields = {"rig": rig, "rig_hash": rig.hash, "cameras": tuple(rig.names), "image_size": image_size}
    return meta.model_copy(update={**fields, "model_id": model_id, **update})


def _virtual(
    proto: onnx.ModelProto,
    props: dict[str, str],
    meta: ArtifactMeta,
    robot: Rig,
    camera_map: Mapping[str, str] | None,
    depth: float | None,
) -> tuple[ArtifactMeta, dict[str, str]]:
    """The front end for ``robot`` attached to ``proto``, FisheyePETR's keys on unseen pixels masked; the new
    metadata and its extra entries."""
    training = meta.training_rig
    order = map_cameras(training, robot, camera_map)
    ordered = robot.model_copy(update={"cameras": tuple(robot.camera(name) for name in order)})
    front = virtual_front(training, ordered, order, depth)
    attach_front(proto, front)
    extra = _mask_petr_keys(proto, props, meta, np.stack([view.unseen for view in front.views]))
    cameras = VirtualCameras(training_rig=training, depth_m=depth, unseen_fill=UNSEEN_FILL, cameras=front.reports)
    return _on_rig(meta, ordered, front.padded_size, virtual_cameras=cameras), extra


def _mask_petr_keys(
    proto: onnx.ModelProto, props: dict[str, str], meta: ArtifactMeta, unseen: np.ndarray | None
) -> dict[str, str]:
    """FisheyePETR's key mask set to the trained one raised for the keys that sample ``unseen`` image pixels
    (N, H, W) bool, None for none; the metadata entry that records the trained mask (none for other models).

    The trained mask is the file's own (a checkpoint's stored one where it was exported from a checkpoint) or, for a
    file re-baked before, the one that re-bake recorded. The key embedding keeps the file's position share and
    takes the new mask's share (`remasked_key_embedding`). The keys that sample unseen pixels are found through
    the rig's feature grid.
    """
    if REBAKE_WEIGHTS_KEY not in props:  # only the PETR kinds' files carry weights
        return {}
    geometry = geometry_from_rig(meta.training_rig, meta.geometry)
    if not isinstance(geometry, PETRGeometry):
        return {}
    weights = decode_arrays(props[REBAKE_WEIGHTS_KEY])
    held = initializer_arrays(proto, (PETR_KEY_POS, PETR_KEY_MASK))
    current = held[PETR_KEY_MASK].reshape(geometry.unvalid_area.shape)
    trained = decode_arrays(props[TRAINED_KEY_MASK_KEY])["key_mask"] if TRAINED_KEY_MASK_KEY in props else current
    target = geometry.with_key_mask(trained)
    if unseen is not None:
        target = target.with_unseen(unseen)
    mask = target.key_mask()
    key_pos = remasked_key_embedding(held[PETR_KEY_POS], current, mask, weights, geometry.params)
    replace_initializers(proto, key_tables(key_pos, mask))
    return {TRAINED_KEY_MASK_KEY: encode_arrays({"key_mask": trained})}


def _tables(
    proto: onnx.ModelProto, props: dict[str, str], meta: ArtifactMeta, new_rig: Rig, model_path: Path
) -> tuple[ArtifactMeta, dict[str, str]]:
    """``proto``'s geometry tables recomputed for ``new_rig`` (any front end removed), but for a file whose tables
    came from a checkpoint re-baked onto its training rig, which keeps them; the new metadata and its extra
    entries."""
    training = meta.training_rig
    had_front = has_front(proto)
    if had_front:
        detach_front(proto)
    if len(new_rig) != len(training):
        raise RigError(
            f"the rig has {len(new_rig)} cameras, the model was built for {len(training)} ({', '.join(training.names)})"
        )
    size = (training.cameras[0].model.width, training.cameras[0].model.height)
    new_rig.require(training.names, size)
    if meta.geometry_source == "checkpoint" and new_rig.hash == training.hash:
        extra = _mask_petr_keys(proto, props, meta, None)
        # a virtual file's keys were moved back: its parity notes no longer hold
        return _on_rig(meta, training, size, parity=None if had_front else meta.parity, virtual_cameras=None), extra
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
    # parity: its notes quote table values, which the rig changes
    return _on_rig(meta, new_rig, size, geometry_source="rig", parity=None, virtual_cameras=None), {}
