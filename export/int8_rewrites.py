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
- after quantization, ``data_movement_on_quantized_values`` and ``neighbour_swap_as_concat`` (in
  ``quantized_rewrites``) move reshapes and transposes to the uint8 side of the quantization and
  copy a large uint8 transpose as Split + Concat.

The graph bookkeeping the rewrites share (fresh value names, node order, recorded module paths) is
in ``graph_edit``.
"""

from __future__ import annotations

import math
from collections.abc import Collection

import numpy as np
import onnx
from onnx import helper, numpy_helper

from .graph import readers_of, static_shapes
from .graph_edit import attrs, int64s, like, replace
from .quantized_rewrites import data_movement_on_quantized_values, neighbour_swap_as_concat

__all__ = [
    "before_quantization",
    "after_quantization",
    "stem_as_space_to_depth",
    "upsample_as_depth_to_space",
]

#: A stride-2 convolution over at most this many input channels is a stem worth rewriting.
STEM_MAX_CHANNELS = 4


def before_quantization(model: onnx.ModelProto, quantized: Collection[str] | None = None) -> list[str]:
    """Apply the fp32-graph rewrites in place to the nodes named in ``quantized`` (default: all);
    returns the names of the nodes rewritten. A layer that stays float keeps its form."""
    return stem_as_space_to_depth(model, quantized) + upsample_as_depth_to_space(model, quantized)


def after_quantization(model: onnx.ModelProto) -> list[str]:
    """Apply the QDQ-graph rewrites in place (``quantized_rewrites``); returns the names of the nodes moved
    or rewritten."""
    return data_movement_on_quantized_values(model) + neighbour_swap_as_concat(model)


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
            or list(attrs(transpose).get("perm", [])) != [0, 3, 1, 2]
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
        graph.initializer.extend([int64s(split, [0, h, 2, wd, 2, c]), int64s(merged, [0, h, wd, 4 * c])])
        chain = [
            like(helper.make_node("Reshape", [source, split], [f"{name}.rows2"], name=f"{name}.blocks.split"), conv),
            like(
                helper.make_node(
                    "Transpose",
                    [f"{name}.rows2"],
                    [f"{name}.blocks6"],
                    name=f"{name}.blocks.gather",
                    perm=[0, 1, 3, 2, 4, 5],
                ),
                conv,
            ),
            like(
                helper.make_node(
                    "Reshape", [f"{name}.blocks6", merged], [f"{name}.blocks_nhwc"], name=f"{name}.blocks.merge"
                ),
                conv,
            ),
            like(
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
        conv_attrs = attrs(conv)
        conv_attrs.update(kernel_shape=[blocks, blocks], strides=[1, 1], pads=[begin, begin, end_h, end_w])
        conv_attrs.pop("auto_pad", None)
        new_conv = like(
            helper.make_node(
                "Conv", [chain[-1].output[0], *conv.input[1:]], list(conv.output), name=name, **conv_attrs
            ),
            conv,
        )
        readers[transpose.output[0]].remove(conv)
        replace(graph, [conv] + ([transpose] if not readers[transpose.output[0]] else []), [*chain, new_conv])
        changed.append(name)
    return changed


def _stem_plan(
    conv: onnx.NodeProto, weight_shape: tuple[int, ...], nhwc: tuple[int, ...] | None
) -> tuple[int, int, int, int, int] | None:
    """(kernel in blocks, shift e, front padding in blocks, end padding in blocks (rows, columns)), or ``None``."""
    conv_attrs = attrs(conv)
    _, c, k, k2 = weight_shape
    pads = list(conv_attrs.get("pads", [0, 0, 0, 0]))
    if (
        nhwc is None
        or len(nhwc) != 4
        or nhwc[3] != c
        or c > STEM_MAX_CHANNELS
        or k != k2
        or any(d <= 0 or d % 2 for d in nhwc[1:3])
        or list(conv_attrs.get("strides", [1, 1])) != [2, 2]
        or conv_attrs.get("group", 1) != 1
        or list(conv_attrs.get("dilations", [1, 1])) != [1, 1]
        or conv_attrs.get("auto_pad", b"NOTSET") not in (b"NOTSET", "NOTSET")
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
            like(helper.make_node("Conv", list(node.input), [blocks], name=f"{name}.conv", kernel_shape=[1, 1]), node)
        ]
        if relu is not None:
            chain.append(
                like(helper.make_node("Relu", [blocks], [f"{blocks}.relu"], name=relu.name or f"{name}.relu"), relu)
            )
        final = (relu or node).output[0]
        chain.append(
            like(
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
        replace(graph, [node] + ([relu] if relu is not None else []), chain)
        changed.append(name)
    return changed


def _is_block_upsample(node: onnx.NodeProto, weight_shape: tuple[int, ...]) -> bool:
    """ConvTranspose with kernel = stride (square, > 1), group 1, no padding, dilation or output padding."""
    node_attrs = attrs(node)
    k = list(weight_shape[2:])
    pad_free = (
        node_attrs.get("auto_pad", b"NOTSET") in (b"NOTSET", b"VALID", "NOTSET", "VALID")
        and not any(node_attrs.get("pads", [0]))
        and not any(node_attrs.get("output_padding", [0]))
        and "output_shape" not in node_attrs
    )
    return (
        len(k) == 2
        and k[0] == k[1] > 1
        and list(node_attrs.get("strides", [1, 1])) == k
        and list(node_attrs.get("kernel_shape", k)) == k
        and node_attrs.get("group", 1) == 1
        and list(node_attrs.get("dilations", [1, 1])) == [1, 1]
        and pad_free
    )
