"""``to_float16``: a verified fp32 graph -> the same graph computing in float16, for GPU execution providers.

    half, plan = to_float16(onnx.load("model.onnx"))      # plan: what stayed float32 and why

GPUs run float16 at several times the float32 rate, and TensorRT / the CUDA execution provider
take a float16 graph as it is. The conversion is written with ``onnx`` helpers alone: every
FLOAT weight and value becomes FLOAT16, and Casts are inserted where a float16 value meets a
float32 one, except for what float16 would get wrong:

- the graph's interface: ``images`` (uint8) and ``camera_valid`` (bool) in, float32 ``boxes``
  and ``scores`` out (cast back at the end), int64 ``labels``, bool ``valid``: a runtime feeds
  and reads the fp16 file exactly like the fp32 one;
- the geometry tables (``geom.*``) stay float32 initializers: ``rebake`` swaps them by name and
  dtype, and a float16 consumer reads them through a Cast;
- index arithmetic: float values computed from integers (a top-k index divided by the class
  count and floored) stay float32, since float16 holds integers exactly only up to 2048;
- the nodes named in ``keep`` (none by default: the warp's bilinear weights, read through a
  Cast, are rounded by at most 2.4e-4 in float16, half a float16 step below 1), and any input an
  operator's schema types as float32 only (Resize's scales).

Weights beyond float16's range are clipped to +-65504 and counted in the plan.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np
import onnx
from onnx import TensorProto, numpy_helper

from fisheye_infer.errors import ExportError
from fisheye_infer.geometry.tables import PREFIX as GEOMETRY_PREFIX

__all__ = ["GEOMETRY_PREFIX", "Float16Plan", "to_float16"]

_FLOAT, _HALF = TensorProto.FLOAT, TensorProto.FLOAT16
_INTEGERS = {
    TensorProto.INT64,
    TensorProto.INT32,
    TensorProto.INT16,
    TensorProto.INT8,
    TensorProto.UINT64,
    TensorProto.UINT32,
    TensorProto.UINT16,
}
_HALF_MAX = float(np.finfo(np.float16).max)
#: Ops that read only the shape of their input: whatever its precision, no Cast is needed.
_SHAPE_READERS = ("Shape", "Size")


@dataclass(frozen=True)
class Float16Plan:
    """What ``to_float16`` did: counts for the file's metadata and the export summary."""

    nodes: int
    half_nodes: int
    kept_nodes: tuple[str, ...]  # the ``keep`` nodes found in the graph
    index_nodes: int  # float32 index arithmetic
    geometry_tables: int  # geom.* initializers left float32
    casts: int  # Cast nodes inserted
    clipped_weights: int  # weight values beyond float16's range, clipped

    def scope(self) -> str:
        kept = f"; kept float32: {', '.join(self.kept_nodes)}" if self.kept_nodes else ""
        clipped = f"; {self.clipped_weights} weight value(s) clipped to +-65504" if self.clipped_weights else ""
        return (
            f"float16 weights and compute in {self.half_nodes} of {self.nodes} nodes; float32: {self.geometry_tables} "
            f"geometry tables (geom.*), {self.index_nodes} index-arithmetic node(s){kept}; {self.casts} Casts "
            f"inserted{clipped}; uint8/bool inputs and float32 outputs as in fp32"
        )


def _types(model: onnx.ModelProto) -> dict[str, int]:
    try:
        inferred = onnx.shape_inference.infer_shapes(model, strict_mode=True)
    except Exception as exc:  # the checker's errors are untyped
        raise ExportError(
            f"fp16: ONNX shape inference fails on the fp32 graph ({exc}); cannot tell float values apart"
        ) from exc
    graph = inferred.graph
    types = {
        v.name: v.type.tensor_type.elem_type for v in list(graph.value_info) + list(graph.input) + list(graph.output)
    }
    types.update({i.name: i.data_type for i in graph.initializer})
    return types


def _half_slot(node: onnx.NodeProto, index: int, opset: int, output: bool = False) -> bool:
    """Whether the operator's schema lets input (or output) ``index`` of ``node`` be float16."""
    schema = onnx.defs.get_schema(node.op_type, opset, node.domain)
    formals = schema.outputs if output else schema.inputs
    formal = formals[min(index, len(formals) - 1)]  # a variadic last parameter covers the rest
    allowed = next(
        (c.allowed_type_strs for c in schema.type_constraints if c.type_param_str == formal.type_str), [formal.type_str]
    )
    return "tensor(float16)" in allowed


def _to_half_tensor(tensor: TensorProto) -> tuple[TensorProto, int]:
    array = numpy_helper.to_array(tensor)
    clipped = int(np.count_nonzero(np.abs(array) > _HALF_MAX))
    return numpy_helper.from_array(np.clip(array, -_HALF_MAX, _HALF_MAX).astype(np.float16), tensor.name), clipped


def to_float16(model: onnx.ModelProto, keep: Iterable[str] = ()) -> tuple[onnx.ModelProto, Float16Plan]:
    """A float16 copy of ``model`` (see the module docstring) and what stayed float32; ``model`` is untouched."""
    keep = set(keep)
    if any(a.HasField("g") or a.graphs for n in model.graph.node for a in n.attribute):
        raise ExportError("fp16: the graph has subgraphs (If/Loop/Scan); only flat graphs are converted")
    types = _types(model)
    opset = max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx"))
    out = onnx.ModelProto()
    out.CopyFrom(model)
    graph = out.graph
    nodes = list(graph.node)

    # 1. which nodes compute in float16
    index_values: set[str] = set()  # float values derived from integers
    half: dict[int, bool] = {}
    index_nodes = 0
    for i, node in enumerate(nodes):
        float_in = [n for n in node.input if types.get(n) == _FLOAT]
        from_integer = (
            node.op_type == "Cast" and types.get(node.input[0]) in _INTEGERS and types.get(node.output[0]) == _FLOAT
        )
        if from_integer or any(n in index_values for n in float_in):
            index_values.update(o for o in node.output if types.get(o) == _FLOAT)
            half[i] = False
            index_nodes += 1
            continue
        float_out = [k for k, o in enumerate(node.output) if types.get(o) == _FLOAT]
        half[i] = node.name not in keep and all(_half_slot(node, k, opset, output=True) for k in float_out)

    # 2. where each float value lives: float16 when a float16 node makes it, or a weight only float16 nodes read
    stored_half = {o for i, node in enumerate(nodes) if half[i] for o in node.output if types.get(o) == _FLOAT}
    wants: dict[str, set[bool]] = {}
    for i, node in enumerate(nodes):
        for k, name in enumerate(node.input):
            if types.get(name) == _FLOAT and node.op_type not in _SHAPE_READERS:
                wants.setdefault(name, set()).add(half[i] and _half_slot(node, k, opset))
    clipped = 0
    geometry = 0
    graph_inputs = {v.name for v in graph.input}
    for init in graph.initializer:
        if init.data_type != _FLOAT or init.name in graph_inputs:
            continue
        if init.name.startswith(GEOMETRY_PREFIX):
            geometry += 1
        elif wants.get(init.name) == {True}:
            new, n = _to_half_tensor(init)
            init.CopyFrom(new)
            clipped += n
            stored_half.add(init.name)

    # 3. attributes of float16 nodes, and Casts where a value's precision is not its reader's
    casts: dict[tuple[str, int], str] = {}
    rewired: list[onnx.NodeProto] = []
    for i, node in enumerate(nodes):
        for k, name in enumerate(node.input):
            if types.get(name) != _FLOAT or node.op_type in _SHAPE_READERS:
                continue
            want_half = half[i] and _half_slot(node, k, opset)
            if want_half != (name in stored_half):
                to = _HALF if want_half else _FLOAT
                if (name, to) not in casts:
                    casts[(name, to)] = f"{name}.{'fp16' if want_half else 'fp32'}"
                    rewired.append(
                        onnx.helper.make_node(
                            "Cast", [name], [casts[(name, to)]], name=f"cast_{casts[(name, to)]}", to=to
                        )
                    )
                node.input[k] = casts[(name, to)]
        if half[i]:
            clipped += _half_attributes(node)
        rewired.append(node)

    # 4. float32 graph outputs: the float16 value under another name, cast back
    tail = []
    for value in graph.output:
        if value.name in stored_half:
            inner = f"{value.name}.fp16"
            for node in rewired:
                node.input[:] = [inner if n == value.name else n for n in node.input]
                node.output[:] = [inner if n == value.name else n for n in node.output]
            tail.append(onnx.helper.make_node("Cast", [inner], [value.name], name=f"cast_{value.name}_fp32", to=_FLOAT))
    del graph.node[:]
    graph.node.extend(rewired + tail)
    del graph.value_info[:]
    try:
        onnx.checker.check_model(out)
        onnx.shape_inference.infer_shapes(out, strict_mode=True)
    except Exception as exc:
        raise ExportError(f"fp16: the converted graph is not valid ONNX ({exc})") from exc
    plan = Float16Plan(
        nodes=len(nodes),
        half_nodes=sum(half.values()),
        kept_nodes=tuple(n.name for n in nodes if n.name in keep),
        index_nodes=index_nodes,
        geometry_tables=geometry,
        casts=len(casts) + len(tail),
        clipped_weights=clipped,
    )
    return out, plan


def _half_attributes(node: onnx.NodeProto) -> int:
    """Make a float16 node's float32 attributes float16 (Cast targets, constant values); returns clipped values."""
    clipped = 0
    for attr in node.attribute:
        if node.op_type == "Cast" and attr.name == "to" and attr.i == _FLOAT:
            attr.i = _HALF
        elif node.op_type in ("Constant", "ConstantOfShape") and attr.name == "value" and attr.t.data_type == _FLOAT:
            new, clipped = _to_half_tensor(attr.t)
            attr.t.CopyFrom(new)
    if node.op_type == "ConstantOfShape" and not any(
        a.name == "value" for a in node.attribute
    ):  # the default is a float32 zero
        node.attribute.append(onnx.helper.make_attribute("value", numpy_helper.from_array(np.zeros(1, np.float16))))
    if node.op_type == "Constant" and any(a.name in ("value_float", "value_floats") for a in node.attribute):
        attr = next(a for a in node.attribute if a.name in ("value_float", "value_floats"))
        value = np.array(attr.f if attr.name == "value_float" else list(attr.floats), np.float16)
        node.ClearField("attribute")
        node.attribute.append(onnx.helper.make_attribute("value", numpy_helper.from_array(value)))
    return clipped
