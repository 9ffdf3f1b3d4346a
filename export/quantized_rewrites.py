"""Exact rewrites of a quantized (QDQ) graph that let ONNX Runtime move uint8 values instead of floats.

``int8_rewrites.after_quantization`` applies them to the graph ``quantize_static`` returns; each moves
or copies the same values in another arrangement, so the file computes exactly what it did.

- ``data_movement_on_quantized_values``: a reshape, transpose or depth-to-space next to a per-tensor
  QuantizeLinear / DequantizeLinear moves to the uint8 side of it (it only permutes values, and
  per-tensor (de)quantization acts on each value alike), so it moves a quarter of the bytes, and
  a Concat after it reads only dequantized values again (ONNX Runtime then runs it in uint8).
- ``neighbour_swap_as_concat``: a large uint8 Transpose that exchanges two neighbouring axes, the
  outer of a few entries (the stem's 2x2 blocks: rows of a block before the block's column),
  becomes a Split along that axis and a Concat of the slices one axis further in. ONNX Runtime's
  Transpose moves such a tensor value by value; Concat copies each contiguous run (here six
  values) at once: the shipped model's 4 x 320 x 320 frame 3.4 -> 1.0 ms on one thread, full size
  (800 x 800) 11 -> 4.6 ms.
"""

from __future__ import annotations

import math
from collections.abc import Iterator

import onnx
from onnx import helper

from .graph import readers_of, static_shapes
from .graph_edit import attrs, fresh, int64s, like, position, replace, value_names

__all__ = ["data_movement_on_quantized_values", "neighbour_swap_as_concat"]

#: Ops that only move values; a per-tensor quantization commutes with them.
DATA_MOVEMENT = ("Reshape", "Transpose", "DepthToSpace", "SpaceToDepth")
#: A uint8 neighbouring-axes Transpose becomes Split + Concat when its outer axis has at most this
#: many entries (one slice each), each copy moves at least ``SWAP_MIN_RUN`` contiguous values, and a
#: batch item holds at least ``SWAP_MIN_VALUES`` values; elsewhere Transpose is as fast or faster.
SWAP_MAX_SLICES = 4
SWAP_MIN_RUN = 2
SWAP_MIN_VALUES = 1 << 16


def data_movement_on_quantized_values(model: onnx.ModelProto) -> list[str]:
    """Move value-permuting ops to the uint8 side of per-tensor quantization; returns the ops moved.

    ``DequantizeLinear -> DepthToSpace`` becomes ``DepthToSpace -> DequantizeLinear``; a chain of
    Reshape / Transpose / DepthToSpace / SpaceToDepth ending in ``QuantizeLinear`` gets the
    QuantizeLinear at its start. Only where each moved value has that one reader and the scale and
    zero point are scalars.
    """
    graph = model.graph
    inits = {i.name: i for i in graph.initializer}
    taken = value_names(graph)
    moved: list[str] = []

    def per_tensor(node: onnx.NodeProto) -> bool:
        return all(name in inits and len(inits[name].dims) == 0 for name in node.input[1:3] if name)

    readers = readers_of(graph)
    for dq in [n for n in graph.node if n.op_type == "DequantizeLinear" and per_tensor(n)]:
        after = readers.get(dq.output[0], [])
        if dq.input[0] in inits or len(after) != 1 or after[0].op_type not in ("DepthToSpace", "SpaceToDepth"):
            continue
        move = after[0]
        i, j = position(graph, dq), position(graph, move)
        quantized = fresh(taken, f"{move.output[0]}.quantized")
        first, second = onnx.NodeProto(), onnx.NodeProto()
        first.CopyFrom(move)  # the permutation, now on the quantized values, where the DequantizeLinear stood
        first.input[0], first.output[0] = dq.input[0], quantized
        second.CopyFrom(dq)  # the DequantizeLinear, now making the permutation's old output
        second.input[0], second.output[0] = quantized, move.output[0]
        graph.node[i].CopyFrom(first)
        graph.node[j].CopyFrom(second)
        moved.append(first.name)

    readers = readers_of(graph)
    producers = {o: n for n in graph.node for o in n.output}
    retyped: set[str] = set()
    for q in [n for n in graph.node if n.op_type == "QuantizeLinear" and per_tensor(n)]:
        chain = list(_movement_chain(q.input[0], producers, readers))
        if not chain:
            continue
        first, last = chain[-1], chain[0]
        at, old_at, moved_q = position(graph, first), position(graph, q), onnx.NodeProto()
        moved_q.CopyFrom(q)
        moved_q.input[0] = first.input[0]
        moved_q.output[0] = fresh(taken, f"{first.input[0]}.quantized")
        retyped.update(n.output[0] for n in chain[1:])  # float before, uint8 now
        first.input[0] = moved_q.output[0]
        last.output[0] = q.output[0]
        del graph.node[old_at]  # after the chain, so ``at`` still points at its start
        graph.node.insert(at, moved_q)
        moved.extend(n.name for n in reversed(chain))
    stale = [v for v in graph.value_info if v.name in retyped]
    for info in stale:
        graph.value_info.remove(info)
    return moved


def _movement_chain(
    value: str, producers: dict[str, onnx.NodeProto], readers: dict[str, list[onnx.NodeProto]]
) -> Iterator[onnx.NodeProto]:
    """The data-movement nodes that lead to ``value``, nearest first, each the only reader of its input."""
    node = producers.get(value)
    while node is not None and node.op_type in DATA_MOVEMENT and len(readers.get(node.output[0], [])) == 1:
        yield node
        source = node.input[0]
        if len(readers.get(source, [])) != 1:
            return
        node = producers.get(source)


def neighbour_swap_as_concat(model: onnx.ModelProto) -> list[str]:
    """Rewrite a uint8 Transpose that exchanges axes ``a`` and ``a + 1`` as Split + Concat; returns their names.

    Slice ``j`` of the input along ``a`` is ``x[..., j:j+1, :, ...]``; moving its unit axis one place
    further in is a Reshape (the values keep their order), and concatenating the slices along
    ``a + 1`` puts ``x[..., j, i, ...]`` at ``[..., i, j, ...]``: the transposed tensor. Only where
    that was measured faster: uint8 values (ONNX Runtime's float Transpose is as fast or faster),
    ``a`` after the batch axis with 2 to ``SWAP_MAX_SLICES`` entries, contiguous runs of at least
    ``SWAP_MIN_RUN`` values behind ``a + 1`` (with runs of one value Concat is slower), the
    dimensions from ``a`` on known, and at least ``SWAP_MIN_VALUES`` values per batch item.
    Dimensions before ``a`` are copied (Reshape's 0), so the batch may be symbolic.
    """
    graph = model.graph
    inferred = onnx.shape_inference.infer_shapes(model).graph
    uint8 = {
        v.name
        for v in [*inferred.value_info, *inferred.input]
        if v.type.tensor_type.elem_type == onnx.TensorProto.UINT8
    }
    shapes = static_shapes(model)
    taken = value_names(graph)
    names = {n.name for n in graph.node}
    changed: list[str] = []
    for node in [n for n in graph.node if n.op_type == "Transpose" and n.input[0] in uint8]:
        perm = list(attrs(node).get("perm", []))
        moved = [i for i, p in enumerate(perm) if p != i]
        shape = shapes.get(node.input[0])
        if len(moved) != 2 or moved[1] != moved[0] + 1 or moved[0] == 0 or shape is None or len(shape) != len(perm):
            continue
        a = moved[0]
        tail = shape[a:]
        if (
            any(d <= 0 for d in tail)
            or not 2 <= tail[0] <= SWAP_MAX_SLICES
            or math.prod(tail[2:]) < SWAP_MIN_RUN
            or math.prod(d for d in shape[1:] if d > 0) < SWAP_MIN_VALUES
        ):
            continue
        name = node.name or node.output[0]
        sizes, piece = fresh(taken, f"{name}.slice_sizes"), fresh(taken, f"{name}.slice_shape")
        graph.initializer.extend([int64s(sizes, [1] * tail[0]), int64s(piece, [0] * a + [tail[1], 1, *tail[2:]])])
        slices = [fresh(taken, f"{name}.slice{j}") for j in range(tail[0])]
        moved_slices = [fresh(taken, f"{name}.slice{j}.moved") for j in range(tail[0])]
        chain = [
            like(
                helper.make_node("Split", [node.input[0], sizes], slices, name=fresh(names, f"{name}.split"), axis=a),
                node,
            )
        ]
        chain += [
            like(helper.make_node("Reshape", [s, piece], [m], name=fresh(names, f"{name}.move{j}")), node)
            for j, (s, m) in enumerate(zip(slices, moved_slices, strict=True))
        ]
        chain.append(
            like(helper.make_node("Concat", moved_slices, list(node.output), name=node.name, axis=a + 1), node)
        )
        replace(graph, [node], chain)
        changed.append(name)
    return changed
