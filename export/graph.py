"""ONNX graph surgery with the ``onnx`` package only (no torch): names, initializers, metadata.

The exporter traces a model with its geometry tables as graph *inputs* (so the tracer can
neither fold them into other constants nor bake their sizes into the graph), then turns those
inputs into named initializers here. ``rebake`` swaps the same initializers for a new rig.
"""

from __future__ import annotations

import base64
import io
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path

import numpy as np
import onnx
from onnx import numpy_helper

from fisheye_infer.artifact import METADATA_KEY, ArtifactMeta
from fisheye_infer.errors import ArtifactError, ExportError

__all__ = [
    "REBAKE_WEIGHTS_KEY",
    "STANDARD_DOMAINS",
    "rename_values",
    "inputs_to_initializers",
    "replace_initializers",
    "strip_shape_info",
    "without_outputs",
    "with_outputs",
    "check_standard_ops",
    "set_metadata",
    "get_metadata",
    "encode_arrays",
    "decode_arrays",
    "save_model",
]

#: A second metadata key, present when re-baking needs weights (FisheyePETR's key embedding).
REBAKE_WEIGHTS_KEY = "fisheye_infer.rebake_weights"
STANDARD_DOMAINS = ("", "ai.onnx")


def rename_values(model: onnx.ModelProto, mapping: Mapping[str, str]) -> None:
    """Rename graph inputs/outputs/initializers and every node reference, in place."""
    graph = model.graph
    for value in list(graph.input) + list(graph.output) + list(graph.value_info):
        if value.name in mapping:
            value.name = mapping[value.name]
    for init in graph.initializer:
        if init.name in mapping:
            init.name = mapping[init.name]
    for node in graph.node:
        node.input[:] = [mapping.get(n, n) for n in node.input]
        node.output[:] = [mapping.get(n, n) for n in node.output]


def inputs_to_initializers(model: onnx.ModelProto, tables: Mapping[str, np.ndarray]) -> None:
    """Graph inputs named like ``tables`` become initializers holding those arrays."""
    graph = model.graph
    present = {i.name for i in graph.input}
    missing = set(tables) - present
    if missing:
        raise ExportError(f"the traced graph has no input for geometry tables {sorted(missing)}")
    kept = [i for i in graph.input if i.name not in tables]
    del graph.input[:]
    graph.input.extend(kept)
    for name, array in tables.items():
        graph.initializer.append(numpy_helper.from_array(np.ascontiguousarray(array), name))


def replace_initializers(model: onnx.ModelProto, tables: Mapping[str, np.ndarray]) -> None:
    """Swap the data of existing initializers, keeping names and dtypes; shapes may change."""
    by_name = {init.name: init for init in model.graph.initializer}
    missing = set(tables) - set(by_name)
    if missing:
        raise ArtifactError(f"the model has no geometry initializers {sorted(missing)}")
    for name, array in tables.items():
        old = by_name[name]
        new = numpy_helper.from_array(np.ascontiguousarray(array), name)
        if new.data_type != old.data_type:
            raise ArtifactError(f"initializer {name}: new table is {array.dtype}, the graph holds {onnx.TensorProto.DataType.Name(old.data_type)}")
        old.CopyFrom(new)


def strip_shape_info(model: onnx.ModelProto) -> None:
    """Drop inferred intermediate shapes; after re-baking they could be stale. ORT infers them again."""
    del model.graph.value_info[:]


def without_outputs(model: onnx.ModelProto, names: Sequence[str]) -> onnx.ModelProto:
    """A copy of ``model`` whose graph no longer outputs ``names``; nodes nothing reads any more go too."""
    out = onnx.ModelProto()
    out.CopyFrom(model)
    graph = out.graph
    missing = set(names) - {o.name for o in graph.output}
    if missing:
        raise ExportError(f"the graph has no outputs {sorted(missing)}")
    kept = [o for o in graph.output if o.name not in names]
    del graph.output[:]
    graph.output.extend(kept)
    needed = {o.name for o in kept}
    nodes = []
    for node in reversed(graph.node):
        if any(name in needed for name in node.output):
            nodes.append(node)
            needed.update(_reads(node))
    del graph.node[:]
    graph.node.extend(reversed(nodes))
    inits = [i for i in graph.initializer if i.name in needed]
    del graph.initializer[:]
    graph.initializer.extend(inits)
    return out


def with_outputs(model: onnx.ModelProto, outputs: Mapping[str, int]) -> onnx.ModelProto:
    """A copy of ``model`` that also outputs the intermediate values ``outputs`` (name -> ONNX element type)."""
    produced = {name for node in model.graph.node for name in node.output}
    missing = sorted(set(outputs) - produced)
    if missing:
        raise ExportError(f"the graph computes no values named {missing}")
    out = onnx.ModelProto()
    out.CopyFrom(model)
    present = {o.name for o in out.graph.output}
    out.graph.output.extend(onnx.helper.make_tensor_value_info(name, elem, None) for name, elem in outputs.items() if name not in present)
    return out


def _reads(node: onnx.NodeProto) -> Iterator[str]:
    """Every value ``node`` reads, those of its subgraphs (If, Loop, Scan) included."""
    yield from (n for n in node.input if n)
    for attr in node.attribute:
        for sub in [attr.g] if attr.HasField("g") else list(attr.graphs):
            for inner in sub.node:
                yield from _reads(inner)


def check_standard_ops(model: onnx.ModelProto, min_opset: int = 18) -> None:
    """Refuse custom or contrib ops and opsets below ``min_opset``."""
    custom = sorted({f"{n.domain}::{n.op_type}" for n in model.graph.node if n.domain not in STANDARD_DOMAINS})
    if custom:
        raise ExportError(f"the graph uses non-standard ops: {', '.join(custom)}")
    if model.functions:
        raise ExportError(f"the graph holds local functions ({', '.join(f.name for f in model.functions)}); expected plain ops")
    opset = max((o.version for o in model.opset_import if o.domain in STANDARD_DOMAINS), default=0)
    if opset < min_opset:
        raise ExportError(f"the graph uses opset {opset}; at least {min_opset} is required")


def set_metadata(model: onnx.ModelProto, meta: ArtifactMeta, extra: Mapping[str, str] | None = None) -> None:
    """Write the metadata document (and extra keys), replacing earlier values."""
    entries = {METADATA_KEY: meta.model_dump_json(), **(extra or {})}
    kept = [p for p in model.metadata_props if p.key not in entries]
    del model.metadata_props[:]
    model.metadata_props.extend(kept)
    for key, value in entries.items():
        model.metadata_props.add(key=key, value=value)


def get_metadata(model: onnx.ModelProto) -> dict[str, str]:
    return {p.key: p.value for p in model.metadata_props}


def encode_arrays(arrays: Mapping[str, np.ndarray]) -> str:
    """Arrays -> one base64 npz string for a metadata value."""
    buf = io.BytesIO()
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})
    return base64.b64encode(buf.getvalue()).decode("ascii")


def decode_arrays(text: str) -> dict[str, np.ndarray]:
    with np.load(io.BytesIO(base64.b64decode(text))) as npz:
        return {k: npz[k] for k in npz.files}


def save_model(model: onnx.ModelProto, path: str | Path) -> Path:
    """Write one self-contained file (weights inside, no external data)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    onnx.save_model(model, str(path), save_as_external_data=False)
    return path

