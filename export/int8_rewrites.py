"""Exact rewrites that let ONNX Runtime run more of an int8 file in int8.

``quantize`` applies ``before_quantization`` to the fp32 graph it quantizes and
``after_quantization`` to the QDQ graph it gets back; the fp32 file itself is never changed,
because in float these forms are not faster. Each rewrite computes the same function (the
same products and sums, in another arrangement); only float rounding order may differ.

- ``stem_as_space_to_depth``: a stride-2 convolution over a few channels (the ResNet stem:
  7x7, 3 channels) becomes a stride-1 convolution over 4x the channels of a space-to-depth of its
  input. ONNX Runtime's int8 convolution with 3 input channels is no faster than float; with 12
  it runs about 2x faster.
- ``upsample_as_depth_to_space``: a ConvTranspose with kernel = stride (SECONDFPN's upsampling)
  becomes a 1x1 Conv to ``s * s`` times the channels and a DepthToSpace. ONNX Runtime has no int8
  ConvTranspose kernel; the Conv runs in int8.
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
from collections.abc import Collection, Iterator
from typing import Any

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .graph import readers_of, static_shapes

__all__ = [
    "before_quantization",
    "after_quantization",
    "stem_as_space_to_depth",
    "upsample_as_depth_to_space",
    "data_movement_on_quantized_values",
    "neighbour_swap_as_concat",
]

#: A stride-2 convolution over at most this many input channels is a stem worth rewriting.
STEM_MAX_CHANNELS = 4
#: Ops that only move values; a per-tensor quantization commutes with them.
DATA_MOVEMENT = ("Reshape", "Transpose", "DepthToSpace", "SpaceToDepth")
#: A uint8 neighbouring-axes Transpose becomes Split + Concat when its outer axis has at most this
#: many entries (one slice each), each copy moves at least ``SWAP_MIN_RUN`` contiguous values, and a
#: batch item holds at least ``SWAP_MIN_VALUES`` values; elsewhere Transpose is as fast or faster.
SWAP_MAX_SLICES = 4
SWAP_MIN_RUN = 2
SWAP_MIN_VALUES = 1 << 16


def before_quantization(model: onnx.ModelProto, quantized: Collection[str] | None = None) -> list[str]:
    """Apply the fp32-graph rewrites in place to the nodes named in ``quantized`` (default: all);
    returns the names of the nodes rewritten. A layer that stays float keeps its form."""
    return stem_as_space_to_depth(model, quantized) + upsample_as_depth_to_space(model, quantized)


def after_quantization(model: onnx.ModelProto) -> list[str]:
    """Apply the QDQ-graph rewrites in place; returns the names of the nodes moved or rewritten."""
    return data_movement_on_quantized_values(model) + neighbour_swap_as_concat(model)


# -- helpers ---------------------------------------------------------------------------------------


def _attrs(node: onnx.NodeProto) -> dict[str, Any]:
    return {a.name: helper.get_attribute_value(a) for a in node.attribute}


def _int64s(name: str, values: list[int]) -> onnx.TensorProto:
    return numpy_helper.from_array(np.asarray(values, dtype=np.int64), name)


def _value_names(graph: onnx.GraphProto) -> set[str]:
    return (
        {i.name for i in graph.input} | {i.name for i in graph.initializer} | {o for n in graph.node for o in n.output}
    )


def _fresh(taken: set[str], base: str) -> str:
    """A value name not yet in ``taken`` (which it joins)."""
    name, k = base, 1
    while name in taken:
        name, k = f"{base}.{k}", k + 1
    taken.add(name)
    return name


def _position(graph: onnx.GraphProto, node: onnx.NodeProto) -> int:
    """Index of ``node`` in the graph, found by its first output (each value is made once)."""
    return next(i for i, n in enumerate(graph.node) if n.output[0] == node.output[0])


def _replace(graph: onnx.GraphProto, old: list[onnx.NodeProto], new: list[onnx.NodeProto]) -> None:
    """Put ``new`` where the first of ``old`` stood, and drop ``old``."""
    at = min(_position(graph, n) for n in old)
    for node in old:
        del graph.node[_position(graph, node)]
    for k, node in enumerate(new):
        graph.node.insert(at + k, node)


def _like(node: onnx.NodeProto, template: onnx.NodeProto) -> onnx.NodeProto:
    """``node`` with ``template``'s recorded metadata (its module path: int8 scopes read it)."""
    node.metadata_props.extend(template.metadata_props)
    return node


# -- before quantization ---------------------------------------------------------------------------


def stem_as_space_to_depth(model: onnx.ModelProto, only: Collection[str] | None = None) -> list[str]:
    """Rewrite a stride-2 convolution of a channels-last input as a stride-1 one over its 2x2 blocks.

    Matches ``Transpose(perm 0,3,1,2) -> Conv`` with kernel ``k`` (square), stride 2, equal pads
    ``p``, group 1, dilation 1, at most ``STEM_MAX_CHANNELS`` input channels and an N x H x W x C
    input of known, even H and W. Output row ``i`` reads padded input row ``2i + ky`` (``ky < k``).
    With ``P = ceil(p / 2)`` blocks of padding in front and ``e = 2P - p``, that row is block
    ``i + m``, row ``d`` of it, where ``2m + d = ky + e``: a convolution over blocks with kernel
    ``ceil((k + e) / 2)`` whose weight is the original one shifted by ``e`` and zero-filled, on
    ``4C`` channels ordered (row in block, column in block, channel). The blocks come from the
    channels-last input by Reshape and Transpose. The end padding makes the output size equal.
    ``only``: the convolutions that may be rewritten, by name (default: all).
    """
    graph = model.graph
    inits = {i.name: i for i in graph.initializer}
    readers = readers_of(graph)
    producers = {o: n for n in graph.node for o in n.output}
    shapes = static_shapes(model)
    changed: list[str] = []
    for conv in [n for n in graph.node if n.op_type == "Conv" and (only is None or n.name in only)]:
        transpose = producers.get(conv.input[0])
        weight = inits.get(conv.input[1]) if len(conv.input) > 1 else None
        if (
            transpose is None
            or transpose.op_type != "Transpose"
            or list(_attrs(transpose).get("perm", [])) != [0, 3, 1, 2]
            or weight is None
            or len(weight.dims) != 4
            or len(readers[weight.name]) != 1
        ):
            continue
        nhwc = shapes.get(transpose.input[0])
        plan = _stem_plan(conv, tuple(weight.dims), nhwc)
        if plan is None:
            continue
        w = numpy_helper.to_array(weight)
        out_c, c, k, _ = w.shape
        blocks, e, begin, end_h, end_w = plan
        padded = np.zeros((out_c, c, 2 * blocks, 2 * blocks), dtype=w.dtype)
        padded[:, :, e : e + k, e : e + k] = w
        block_weight = (
            padded.reshape(out_c, c, blocks, 2, blocks, 2)
            .transpose(0, 3, 5, 1, 2, 4)
            .reshape(out_c, 4 * c, blocks, blocks)
        )
        weight.CopyFrom(numpy_helper.from_array(np.ascontiguousarray(block_weight), weight.name))
        assert nhwc is not None
        h, wd = nhwc[1] // 2, nhwc[2] // 2
        name = conv.name or conv.output[0]
        source = transpose.input[0]
        split, merged = f"{name}.blocks.split_shape", f"{name}.blocks.shape"
        graph.initializer.extend([_int64s(split, [0, h, 2, wd, 2, c]), _int64s(merged, [0, h, wd, 4 * c])])
        chain = [
            _like(helper.make_node("Reshape", [source, split], [f"{name}.rows2"], name=f"{name}.blocks.split"), conv),
            _like(
                helper.make_node(
                    "Transpose",
                    [f"{name}.rows2"],
                    [f"{name}.blocks6"],
                    name=f"{name}.blocks.gather",
                    perm=[0, 1, 3, 2, 4, 5],
                ),
                conv,
            ),
            _like(
                helper.make_node(
                    "Reshape", [f"{name}.blocks6", merged], [f"{name}.blocks_nhwc"], name=f"{name}.blocks.merge"
                ),
                conv,
            ),
            _like(
                helper.make_node(
                    "Transpose",
                    [f"{name}.blocks_nhwc"],
                    [f"{name}.blocks_nchw"],
                    name=f"{name}.blocks.nchw",
                    perm=[0, 3, 1, 2],
                ),
                conv,
            ),
        ]
        attrs = _attrs(conv)
        attrs.update(kernel_shape=[blocks, blocks], strides=[1, 1], pads=[begin, begin, end_h, end_w])
        attrs.pop("auto_pad", None)
        new_conv = _like(
            helper.make_node("Conv", [chain[-1].output[0], *conv.input[1:]], list(conv.output), name=name, **attrs),
            conv,
        )
        readers[transpose.output[0]].remove(conv)
        _replace(graph, [conv] + ([transpose] if not readers[transpose.output[0]] else []), [*chain, new_conv])
        changed.append(name)
    return changed


def _stem_plan(
    conv: onnx.NodeProto, weight_shape: tuple[int, ...], nhwc: tuple[int, ...] | None
) -> tuple[int, int, int, int, int] | None:
    """(kernel in blocks, shift e, front padding in blocks, end padding in blocks (rows, columns)), or ``None``."""
    attrs = _attrs(conv)
    _, c, k, k2 = weight_shape
    pads = list(attrs.get("pads", [0, 0, 0, 0]))
    if (
        nhwc is None
        or len(nhwc) != 4
        or nhwc[3] != c
        or c > STEM_MAX_CHANNELS
        or k != k2
        or any(d <= 0 or d % 2 for d in nhwc[1:3])
        or list(attrs.get("strides", [1, 1])) != [2, 2]
        or attrs.get("group", 1) != 1
        or list(attrs.get("dilations", [1, 1])) != [1, 1]
        or attrs.get("auto_pad", b"NOTSET") not in (b"NOTSET", "NOTSET")
        or len(set(pads)) != 1
    ):
        return None
    p = pads[0]
    begin = math.ceil(p / 2)
    e = 2 * begin - p
    blocks = math.ceil((k + e) / 2)
    ends = []
    for size in nhwc[1:3]:
        out = (size + 2 * p - k) // 2 + 1
        ends.append(out - 1 + blocks - size // 2 - begin)
    if min(ends) < 0:
        return None
    return blocks, e, begin, ends[0], ends[1]


def upsample_as_depth_to_space(model: onnx.ModelProto, only: Collection[str] | None = None) -> list[str]:
    """Rewrite each non-overlapping ConvTranspose (kernel = stride) as a 1x1 Conv and a DepthToSpace.

    With kernel = stride = ``s``, no padding and no dilation, every output pixel reads exactly one
    input pixel: ``y[o, s*h+i, s*w+j] = sum_c x[c, h, w] W[c, o, i, j] + b[o]``. That is a 1x1
    convolution to ``C_out * s * s`` channels, weight ``W'[o*s*s + i*s + j, c] = W[c, o, i, j]``,
    followed by DepthToSpace in CRD order. A ReLU that alone reads the ConvTranspose moves before
    the DepthToSpace (elementwise, so it commutes), where it belongs to the convolution.
    ``only``: the ConvTranspose nodes that may be rewritten, by name (default: all).
    """
    graph = model.graph
    inits = {i.name: i for i in graph.initializer}
    readers = readers_of(graph)
    changed: list[str] = []
    for node in [n for n in graph.node if n.op_type == "ConvTranspose" and (only is None or n.name in only)]:
        weight = inits.get(node.input[1]) if len(node.input) > 1 else None
        has_bias = len(node.input) > 2 and bool(node.input[2])
        bias = inits.get(node.input[2]) if has_bias else None
        if (
            weight is None
            or len(weight.dims) != 4
            or not _is_block_upsample(node, tuple(weight.dims))
            or len(readers[weight.name]) != 1
            or (has_bias and (bias is None or len(readers[bias.name]) != 1))
        ):
            continue
        w = numpy_helper.to_array(weight)
        cin, cout, s, _ = w.shape
        weight.CopyFrom(
            numpy_helper.from_array(
                np.ascontiguousarray(w.transpose(1, 2, 3, 0)).reshape(cout * s * s, cin, 1, 1), weight.name
            )
        )
        if bias is not None:
            bias.CopyFrom(numpy_helper.from_array(np.repeat(numpy_helper.to_array(bias), s * s), bias.name))
        name = node.name or node.output[0]
        after = readers.get(node.output[0], [])
        relu = after[0] if len(after) == 1 and after[0].op_type == "Relu" else None
        blocks = f"{name}.blocks"
        chain = [
            _like(helper.make_node("Conv", list(node.input), [blocks], name=f"{name}.conv", kernel_shape=[1, 1]), node)
        ]
        if relu is not None:
            chain.append(
                _like(helper.make_node("Relu", [blocks], [f"{blocks}.relu"], name=relu.name or f"{name}.relu"), relu)
            )
        final = (relu or node).output[0]
        chain.append(
            _like(
                helper.make_node(
                    "DepthToSpace",
                    [chain[-1].output[0]],
                    [final],
                    name=f"{name}.depth_to_space",
                    blocksize=s,
                    mode="CRD",
                ),
                node,
            )
        )
        _replace(graph, [node] + ([relu] if relu is not None else []), chain)
        changed.append(name)
    return changed


def _is_block_upsample(node: onnx.NodeProto, weight_shape: tuple[int, ...]) -> bool:
    """ConvTranspose with kernel = stride (square, > 1), group 1, no padding, dilation or output padding."""
    attrs = _attrs(node)
    k = list(weight_shape[2:])
    pad_free = (
        attrs.get("auto_pad", b"NOTSET") in (b"NOTSET", b"VALID", "NOTSET", "VALID")
        and not any(attrs.get("pads", [0]))
        and not any(attrs.get("output_padding", [0]))
        and "output_shape" not in attrs
    )
    return (
        len(k) == 2
        and k[0] == k[1] > 1
        and list(attrs.get("strides", [1, 1])) == k
        and list(attrs.get("kernel_shape", k)) == k
        and attrs.get("group", 1) == 1
        and list(attrs.get("dilations", [1, 1])) == [1, 1]
        and pad_free
    )


# -- after quantization ----------------------------------------------------------------------------


def data_movement_on_quantized_values(model: onnx.ModelProto) -> list[str]:
    """Move value-permuting ops to the uint8 side of per-tensor quantization; returns the ops moved.

    ``DequantizeLinear -> DepthToSpace`` becomes ``DepthToSpace -> DequantizeLinear``; a chain of
    Reshape / Transpose / DepthToSpace / SpaceToDepth ending in ``QuantizeLinear`` gets the
    QuantizeLinear at its start. Only where each moved value has that one reader and the scale and
    zero point are scalars.
    """
    graph = model.graph
    inits = {i.name: i for i in graph.initializer}
    taken = _value_names(graph)
    moved: list[str] = []

    def per_tensor(node: onnx.NodeProto) -> bool:
        return all(name in inits and len(inits[name].dims) == 0 for name in node.input[1:3] if name)

    readers = readers_of(graph)
    for dq in [n for n in graph.node if n.op_type == "DequantizeLinear" and per_tensor(n)]:
        after = readers.get(dq.output[0], [])
        if dq.input[0] in inits or len(after) != 1 or after[0].op_type not in ("DepthToSpace", "SpaceToDepth"):
            continue
        move = after[0]
        i, j = _position(graph, dq), _position(graph, move)
        quantized = _fresh(taken, f"{move.output[0]}.quantized")
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
        at, old_at, moved_q = _position(graph, first), _position(graph, q), onnx.NodeProto()
        moved_q.CopyFrom(q)
        moved_q.input[0] = first.input[0]
        moved_q.output[0] = _fresh(taken, f"{first.input[0]}.quantized")
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
    taken = _value_names(graph)
    names = {n.name for n in graph.node}
    changed: list[str] = []
    for node in [n for n in graph.node if n.op_type == "Transpose" and n.input[0] in uint8]:
        perm = list(_attrs(node).get("perm", []))
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
        sizes, piece = _fresh(taken, f"{name}.slice_sizes"), _fresh(taken, f"{name}.slice_shape")
        graph.initializer.extend([_int64s(sizes, [1] * tail[0]), _int64s(piece, [0] * a + [tail[1], 1, *tail[2:]])])
        slices = [_fresh(taken, f"{name}.slice{j}") for j in range(tail[0])]
        moved_slices = [_fresh(taken, f"{name}.slice{j}.moved") for j in range(tail[0])]
        chain = [
            _like(
                helper.make_node("Split", [node.input[0], sizes], slices, name=_fresh(names, f"{name}.split"), axis=a),
                node,
            )
        ]
        chain += [
            _like(helper.make_node("Reshape", [s, piece], [m], name=_fresh(names, f"{name}.move{j}")), node)
            for j, (s, m) in enumerate(zip(slices, moved_slices, strict=True))
        ]
        chain.append(
            _like(helper.make_node("Concat", moved_slices, list(node.output), name=node.name, axis=a + 1), node)
        )
        _replace(graph, [node], chain)
        changed.append(name)
    return changed
