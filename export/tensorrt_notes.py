"""The notes of ``check_tensorrt`` on element types TensorRT changes: DOUBLE and INT64 data.

A note is accepted by the parser but worth knowing: DOUBLE is cast down to FLOAT; INT64 data
tensors, which TensorRT 10 keeps (the matrix lists INT64 for the ops that carry them) and TensorRT
8.x casts down to INT32, clamping. Unlike the node-by-node checks in ``tensorrt_check``, these look
across the whole graph (an INT64 value counts only when it holds data rather than shapes, which its
readers decide), so they live apart; each says how many values it found, with a few examples.
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto, numpy_helper

from .tensorrt_graph import Findings, GraphFacts, subgraphs
from .tensorrt_matrix import SHAPE_ARITHMETIC, SHAPE_INPUTS

__all__ = ["note_doubles", "note_int64"]

#: INT64 data outside this range is clamped by TensorRT 8.x, which casts INT64 to INT32.
INT32 = np.iinfo(np.int32)
#: How many values a note names as examples.
EXAMPLES = 3


def note_doubles(g: GraphFacts, found: Findings) -> None:
    """One note naming the graph's DOUBLE values, if any: the parser casts them down to FLOAT."""
    doubles = sorted(v for v, t in g.types.items() if t == TensorProto.DOUBLE)
    if doubles:
        found.note(
            None,
            f"{len(doubles)} DOUBLE value(s) (e.g. {', '.join(doubles[:EXAMPLES])}): the parser casts DOUBLE down to "
            "FLOAT, clamping to +-FLT_MAX",
        )


def _shape_like(g: GraphFacts) -> set[str]:
    """Values that only ever hold shapes, axes or counts: every use is a shape input, or shape arithmetic
    whose results are shape-like too. Graph outputs never are."""
    graph = g.model.graph
    uses: dict[str, list[tuple[onnx.NodeProto, int]]] = {}
    for node in graph.node:
        for i, name in enumerate(node.input):
            uses.setdefault(name, []).append((node, i))
    for sub in list(subgraphs(graph))[1:]:  # a value read inside a subgraph: treat as data
        for node in sub.node:
            for name in node.input:
                uses.setdefault(name, []).append((node, -1))
    shape_like: set[str] = set()

    def decide(value: str) -> None:
        if value in g.outputs or not uses.get(value):
            return
        if all(
            i in SHAPE_INPUTS.get(n.op_type, ())
            or (n.op_type in SHAPE_ARITHMETIC and all(o in shape_like for o in n.output if o))
            for n, i in uses[value]
        ):
            shape_like.add(value)

    for node in reversed(graph.node):  # consumers before producers
        for out in node.output:
            decide(out)
    for name in list(g.initializers) + list(g.inputs):
        decide(name)
    return shape_like


def note_int64(g: GraphFacts, found: Findings) -> None:
    """Notes on INT64 data (not shapes): the initializers, with whether their values fit in INT32, and the
    values computed at run time."""
    shape_like = _shape_like(g)
    tables = sorted(
        (i for name, i in g.initializers.items() if i.data_type == TensorProto.INT64 and name not in shape_like),
        key=lambda t: -int(np.prod(t.dims, dtype=np.int64)),
    )  # the largest tables make the best examples
    if tables:
        arrays = [numpy_helper.to_array(t) for t in tables]
        largest = max((int(np.abs(a).max()) for a in arrays if a.size), default=0)
        fits = all(a.size == 0 or (a.min() >= INT32.min and a.max() <= INT32.max) for a in arrays)
        examples = ", ".join(f"{t.name} {tuple(t.dims)}" for t in tables[:EXAMPLES])
        found.note(
            None,
            f"{len(tables)} INT64 initializer(s) hold data, not shapes (e.g. {examples}): TensorRT 10 keeps INT64 "
            f"for the ops the matrix lists it for; TensorRT 8.x casts INT64 down to INT32, clamping to +-2^31-1: "
            + (
                f"every value fits in INT32 (largest |value| {largest})"
                if fits
                else f"values up to {largest} do NOT fit in INT32"
            ),
        )
    values = [
        (node, out)
        for node in g.model.graph.node
        for out in node.output
        if out and g.types.get(out) == TensorProto.INT64 and out not in shape_like
    ]
    if values:
        examples = ", ".join(f"{out} ({node.op_type})" for node, out in values[:EXAMPLES])
        found.note(
            None,
            f"{len(values)} INT64 value(s) computed at run time hold data, not shapes (e.g. {examples}): TensorRT 10 "
            "computes them in INT64; TensorRT 8.x computes them in INT32",
        )
