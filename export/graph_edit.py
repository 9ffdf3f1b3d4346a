"""Small ONNX graph edits shared by the int8 rewrites: read a node's attributes, name new values, and
put new nodes where old ones stood.

``int8_rewrites`` (before quantization) and ``quantized_rewrites`` (after it) both replace a node by
a short chain that computes the same values; these helpers keep that bookkeeping (fresh value names,
graph order, the module path int8 scopes read from node metadata) in one place, so each rewrite reads
as the arithmetic it performs.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import onnx
from onnx import helper, numpy_helper

__all__ = ["attrs", "fresh", "int64s", "like", "position", "replace", "value_names"]


def attrs(node: onnx.NodeProto) -> dict[str, Any]:
    """``node``'s attributes by name, as Python values."""
    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


def int64s(name: str, values: list[int]) -> onnx.TensorProto:
    """An int64 initializer called ``name`` (a shape or split sizes)."""
    return numpy_helper.from_array(np.asarray(values, dtype=np.int64), name)


def value_names(graph: onnx.GraphProto) -> set[str]:
    """Every value name the graph already uses: inputs, initializers and node outputs."""
    return (
        {i.name for i in graph.input} | {i.name for i in graph.initializer} | {o for n in graph.node for o in n.output}
    )


def fresh(taken: set[str], base: str) -> str:
    """A value name not yet in ``taken`` (which it joins)."""
    name, k = base, 1
    while name in taken:
        name, k = f"{base}.{k}", k + 1
    taken.add(name)
    return name


def position(graph: onnx.GraphProto, node: onnx.NodeProto) -> int:
    """Index of ``node`` in the graph, found by its first output (each value is made once)."""
    return next(i for i, n in enumerate(graph.node) if n.output[0] == node.output[0])


def replace(graph: onnx.GraphProto, old: list[onnx.NodeProto], new: list[onnx.NodeProto]) -> None:
    """Put ``new`` where the first of ``old`` stood, and drop ``old``."""
    at = min(position(graph, n) for n in old)
    for node in old:
        del graph.node[position(graph, node)]
    for k, node in enumerate(new):
        graph.node.insert(at + k, node)


def like(node: onnx.NodeProto, template: onnx.NodeProto) -> onnx.NodeProto:
    """``node`` with ``template``'s recorded metadata (its module path: int8 scopes read it)."""
    node.metadata_props.extend(template.metadata_props)
    return node
