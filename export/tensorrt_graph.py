"""What TensorRT's compatibility checks read from an ONNX graph: element types and shapes after shape
inference, constants, values computed from constants alone, and the subgraphs of control-flow nodes.

``tensorrt_check`` decides with these facts; gathering them once keeps each check a few lines that
say what the parser refuses.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import onnx
from onnx import TensorProto, numpy_helper

from fisheye_infer.runtime.artifact import TensorRTFinding

from .tensorrt_matrix import TYPE_NAMES

__all__ = ["Findings", "GraphFacts", "attribute", "subgraphs"]


@dataclass
class GraphFacts:
    """What the checks read: types and shapes after ONNX shape inference, constants, consumers."""

    model: onnx.ModelProto
    types: dict[str, int] = field(default_factory=dict)
    shapes: dict[str, list[int | str | None] | None] = field(default_factory=dict)
    initializers: dict[str, TensorProto] = field(default_factory=dict)
    constants: dict[str, TensorProto] = field(default_factory=dict)  # initializers and Constant outputs
    derived: set[str] = field(default_factory=set)  # computed from constants alone
    outputs: set[str] = field(default_factory=set)
    inputs: set[str] = field(default_factory=set)

    @classmethod
    def read(cls, model: onnx.ModelProto) -> GraphFacts:
        """The facts of ``model`` and its subgraphs, with shape inference run on a copy (best effort)."""
        try:
            inferred = onnx.shape_inference.infer_shapes(model, strict_mode=False)
        except Exception:  # inference is best effort: the checks that need types skip unknown ones
            inferred = model
        g = cls(model)
        for graph in subgraphs(inferred.graph):
            for value in list(graph.value_info) + list(graph.input) + list(graph.output):
                t = value.type.tensor_type
                if t.elem_type:
                    g.types[value.name] = t.elem_type
                g.shapes[value.name] = (
                    [d.dim_value if d.HasField("dim_value") else (d.dim_param or None) for d in t.shape.dim]
                    if t.HasField("shape")
                    else None
                )
            for init in graph.initializer:
                g.types[init.name] = init.data_type
                g.shapes[init.name] = list(init.dims)
        g.inputs = {i.name for i in model.graph.input}
        g.initializers = {i.name: i for i in model.graph.initializer if i.name not in g.inputs}
        g.constants = dict(g.initializers)
        g.outputs = {o.name for o in model.graph.output}
        for node in model.graph.node:
            if node.op_type == "Constant" and node.attribute and node.attribute[0].name == "value":
                g.constants[node.output[0]] = node.attribute[0].t
            elif (
                node.op_type != "Shape"
                and node.input
                and all(not n or n in g.constants or n in g.derived for n in node.input)
            ):
                g.derived.update(node.output)
        return g

    def type_name(self, value: str) -> str | None:
        """The matrix's name for ``value``'s element type (FP32, INT64, ...), or None when inference did not find it."""
        elem = self.types.get(value)
        return None if elem is None else TYPE_NAMES.get(elem, TensorProto.DataType.Name(elem))

    def rank(self, value: str) -> int | None:
        """``value``'s number of dimensions, or None when unknown."""
        shape = self.shapes.get(value)
        return None if shape is None else len(shape)

    def constant(self, value: str) -> np.ndarray | None:
        """``value``'s data when it is an initializer or a Constant's output, else None."""
        tensor = self.constants.get(value)
        return None if tensor is None else numpy_helper.to_array(tensor)


def subgraphs(graph: onnx.GraphProto) -> Iterator[onnx.GraphProto]:
    """``graph`` and every subgraph of its nodes (If, Loop, Scan bodies), depth first."""
    yield graph
    for node in graph.node:
        for attr in node.attribute:
            for sub in [attr.g] if attr.HasField("g") else list(attr.graphs):
                yield from subgraphs(sub)


def attribute(node: onnx.NodeProto, name: str, default: Any = None) -> Any:
    """The value of ``node``'s attribute ``name`` (bytes decoded to str), or ``default`` when it has none.

    Typed ``Any``: the attribute's ONNX type decides (int, float, str, a tensor or a list), and each
    check reads attributes whose type the operator's schema fixes."""
    for a in node.attribute:
        if a.name == name:
            value = onnx.helper.get_attribute_value(a)
            return value.decode() if isinstance(value, bytes) else value
    return default


class Findings(list[TensorRTFinding]):
    """The findings of one check run, in the order the checks make them."""

    def error(self, node: onnx.NodeProto | None, message: str) -> None:
        self.append(
            TensorRTFinding(
                severity="error", node=node.name if node else "", op_type=node.op_type if node else "", message=message
            )
        )

    def note(self, node: onnx.NodeProto | None, message: str) -> None:
        self.append(
            TensorRTFinding(
                severity="note", node=node.name if node else "", op_type=node.op_type if node else "", message=message
            )
        )
