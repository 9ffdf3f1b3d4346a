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

from fisheye_infer.errors import ArtifactError, ExportError
from fisheye_infer.runtime.artifact import METADATA_KEY, ArtifactMeta

__all__ = [
    "REBAKE_WEIGHTS_KEY",
    "TRAINED_KEY_MASK_KEY",
    "STANDARD_DOMAINS",
    "rename_values",
    "inputs_to_initializers",
    "replace_initializers",
    "initializer_arrays",
    "strip_shape_info",
    "without_outputs",
    "with_outputs",
    "check_standard_ops",
    "set_metadata",
    "get_metadata",
    "encode_arrays",
    "decode_arrays",
    "save_model",
    "fold_input_scale",
    "readers_of",
    "static_shapes",
    "GRAPH_OUTPUT_READER",
]

#: A second metadata key, present when re-baking needs weights (FisheyePETR's key embedding).
REBAKE_WEIGHTS_KEY = "fisheye_infer.rebake_weights"
#: FisheyePETR's key mask as trained (before virtual cameras masked unseen pixels), recorded by ``rebake``.
TRAINED_KEY_MASK_KEY = "fisheye_infer.trained_key_mask"
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


def initializer_arrays(model: onnx.ModelProto, names: Sequence[str]) -> dict[str, np.ndarray]:
    """The named initializers of ``model`` as arrays; a missing one is an ``ArtifactError`` naming it."""
    by_name = {init.name: init for init in model.graph.initializer if init.name in names}
    missing = sorted(set(names) - set(by_name))
    if missing:
        raise ArtifactError(f"the model has no initializers {missing}")
    return {name: numpy_helper.to_array(by_name[name]) for name in names}


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
            raise ArtifactError(
                f"initializer {name}: new table is {array.dtype}, the graph holds "
                f"{onnx.TensorProto.DataType.Name(old.data_type)}"
            )
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
    out.graph.output.extend(
        onnx.helper.make_tensor_value_info(name, elem, None) for name, elem in outputs.items() if name not in present
    )
    return out


#: Stands in ``readers_of`` for the model's caller, who reads every graph output.
GRAPH_OUTPUT_READER = onnx.NodeProto(op_type="(graph output)")


def readers_of(graph: onnx.GraphProto) -> dict[str, list[onnx.NodeProto]]:
    """Value name -> the nodes that read it (subgraph reads count for their node), in graph order,
    and ``GRAPH_OUTPUT_READER`` for a graph output: a rewrite may drop or change a value only when
    the node it rewrites is its one reader."""
    readers: dict[str, list[onnx.NodeProto]] = {}
    for node in graph.node:
        for name in _reads(node):
            readers.setdefault(name, []).append(node)
    for out in graph.output:
        readers.setdefault(out.name, []).append(GRAPH_OUTPUT_READER)
    return readers


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
        raise ExportError(
            f"the graph holds local functions ({', '.join(f.name for f in model.functions)}); expected plain ops"
        )
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
    # numpy's stub matches the ** mapping against allow_pickle too
    np.savez_compressed(buf, **{k: np.asarray(v) for k, v in arrays.items()})  # type: ignore[arg-type]
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


def fold_input_scale(model: onnx.ModelProto) -> list[str]:
    """Fold a per-channel division of a convolution's input into its weights; returns the convolutions changed.

    The normalisation ``(x - mean) / std`` ends in a Div by a per-channel constant that feeds the
    first convolution, possibly through Reshapes that keep the channel, height and width axes.
    ``conv(pad0(y / s)) = conv_{W / s}(pad0(y))`` exactly in real arithmetic (zero padding is
    unchanged by scaling, unlike the mean's subtraction), so the Div goes and the weights take
    ``1 / s`` per input channel. In an int8 file that Div ran channels-last, where ONNX Runtime
    broadcasts the three-channel constant element by element.
    """
    graph = model.graph
    inits = {i.name: i for i in graph.initializer}
    consumers = readers_of(graph)
    shapes = static_shapes(model)
    folded: list[str] = []
    for div in [n for n in graph.node if n.op_type == "Div"]:
        scale = _channel_constant(inits.get(div.input[1]))
        if scale is None or len(consumers.get(div.output[0], [])) != 1:
            continue
        node, value = consumers[div.output[0]][0], div.output[0]
        while (
            node.op_type == "Reshape"
            and _keeps_chw(shapes.get(node.input[0]), shapes.get(node.output[0]))
            and len(consumers.get(node.output[0], [])) == 1
        ):
            node, value = consumers[node.output[0]][0], node.output[0]
        weight = inits.get(node.input[1]) if node.op_type == "Conv" and len(node.input) > 1 else None
        group = next((a.i for a in node.attribute if a.name == "group"), 1)
        if (
            weight is None
            or node.input[0] != value
            or group != 1
            or len(consumers[weight.name]) != 1
            or len(weight.dims) != 4
            or weight.dims[1] != scale.size
        ):
            continue
        w = numpy_helper.to_array(weight)
        weight.CopyFrom(
            numpy_helper.from_array((w / scale.astype(w.dtype)[None, :, None, None]).astype(w.dtype), weight.name)
        )
        for reader in consumers[div.output[0]]:
            reader.input[:] = [div.input[0] if i == div.output[0] else i for i in reader.input]
        graph.node.remove(div)
        if not any(div.input[1] in _reads(n) for n in graph.node):
            graph.initializer.remove(inits[div.input[1]])
        folded.append(node.name or node.output[0])
    return folded


def _channel_constant(init: onnx.TensorProto | None) -> np.ndarray | None:
    """The C values of a positive, finite constant shaped (..., C, 1, 1) with ones before C, else ``None``."""
    if init is None or len(init.dims) < 3 or list(init.dims[-2:]) != [1, 1] or any(d != 1 for d in init.dims[:-3]):
        return None
    value = numpy_helper.to_array(init).reshape(-1)
    return value if np.all(np.isfinite(value)) and np.all(value > 0) else None


def _keeps_chw(before: tuple[int, ...] | None, after: tuple[int, ...] | None) -> bool:
    """A Reshape that merges or splits leading axes only: the last three (C, H, W) known and unchanged."""
    return (
        before is not None
        and after is not None
        and len(before) >= 3
        and len(after) >= 3
        and before[-3:] == after[-3:]
        and all(d > 0 for d in before[-3:])
    )


def static_shapes(model: onnx.ModelProto) -> dict[str, tuple[int, ...]]:
    """Value name -> shape from ONNX shape inference, with -1 for a symbolic or unknown dimension."""
    inferred = onnx.shape_inference.infer_shapes(model)
    shapes = {}
    for info in [*inferred.graph.value_info, *inferred.graph.input, *inferred.graph.output]:
        if info.type.HasField("tensor_type") and info.type.tensor_type.HasField("shape"):
            shapes[info.name] = tuple(
                d.dim_value if d.HasField("dim_value") else -1 for d in info.type.tensor_type.shape.dim
            )
    return shapes
