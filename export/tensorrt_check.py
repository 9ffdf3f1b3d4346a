"""``check_tensorrt``: would TensorRT's ONNX parser take this graph? A static check; no TensorRT needed.

    report = check_tensorrt(onnx.load("model.onnx"))   # TensorRTReport: compatible, findings

A file that ONNX Runtime runs on a CPU can still be refused by a GPU runtime: TensorRT imports
ONNX through its own parser, which supports fewer operators, attribute values and data types.
Finding that out at export costs milliseconds; finding it on the robot costs a rebuild. The
rules come from onnx-tensorrt's operator support matrix for TensorRT 10
(``docs/operators.md`` of the ONNX-TensorRT 10.1 GA release: "TensorRT 10.0 supports operators
in the inclusive range of opset 9 to opset 20"), and where the matrix is terse, from the same
release's importer (``onnxOpImporters.cpp``, ``onnxOpCheckers.cpp``), which is what refuses a node (the
matrix itself is data, in ``tensorrt_matrix``; what the checks read of a graph, in ``tensorrt_graph``):

- the opset must be 9 to 20 and every node in the default domain (a custom op needs a plugin);
- every op type must be one the matrix marks supported, and the element type it works on one
  of the matrix's "Supported Types" for it; UINT8 exists only as a network input or output;
- TopK: ``sorted`` = 1 and a constant K of at most 3840 (``ITopKLayer``: "currently only
  values up to 3840 are supported"; the matrix says "less than 3840");
- GridSample: a 4-D input, ``mode`` bilinear, nearest or bicubic (the importer maps any other
  value, e.g. opset 20's "linear" or "cubic", to nearest without a word: silently wrong), and
  ``padding_mode`` zeros, border or reflection;
- ScatterND: no ``reduction`` attribute at all (the importer refuses it even when "none");
- inputs the importer reads as weights must be initializers: Squeeze, Unsqueeze, Slice,
  Reduce* and Pad axes, CumSum's axis, Clip's bounds, Dropout's training_mode, OneHot's depth;
  QuantizeLinear / DequantizeLinear zero points must be zero;
- MaxPool without its Indices output, pooling dilations of one, Resize modes the importer
  knows, LayerNormalization with its first output only, Squeeze without axes on a static shape;
- graph inputs need a known rank, and no tensor may have more than 8 dimensions.

Findings are ``error`` (the parser or the engine build refuses the node; ``compatible`` becomes
False) or ``note`` (accepted, but worth knowing): DOUBLE is cast down to FLOAT; INT64 data
tensors, which TensorRT 10 keeps (the matrix lists INT64 for the ops that carry them) and
TensorRT 8.x cast down to INT32, clamping (both noted by ``tensorrt_notes``); dynamic input
dimensions beyond the batch axis (the engine needs an optimization profile covering them); a
weights-only input computed from constants (fold constants first); a TopK K computed at run time
(cannot be checked here).
"""

from __future__ import annotations

import numpy as np
import onnx
from onnx import TensorProto

from fisheye_infer.runtime.artifact import TensorRTReport

from .tensorrt_graph import Findings, GraphFacts, attribute, subgraphs
from .tensorrt_matrix import (
    FLOAT_TYPES,
    GRID_MODES,
    GRID_PADDING,
    MAX_OPSET,
    MAX_RANK,
    MAX_TOPK_K,
    MIN_OPSET,
    RESIZE_MODES,
    RESIZE_TRANSFORMS,
    SUPPORTED_OPS,
    TARGET,
    UNSUPPORTED_OPS,
    WEIGHTS_INPUTS,
)
from .tensorrt_notes import note_doubles, note_int64

__all__ = [
    "MAX_OPSET",
    "MAX_RANK",
    "MAX_TOPK_K",
    "MIN_OPSET",
    "SUPPORTED_OPS",
    "TARGET",
    "UNSUPPORTED_OPS",
    "check_tensorrt",
]


def check_tensorrt(model: onnx.ModelProto) -> TensorRTReport:
    """Check statically whether TensorRT 10's ONNX parser would take a graph; no TensorRT needed.

    The rules come from onnx-tensorrt's operator support matrix and importer for TensorRT 10: the opset (9 to 20),
    custom domains, supported op types and element types, and the attribute values and constant inputs the
    importer requires (TopK, GridSample, ScatterND, Resize, pooling, Squeeze, Clip, quantization zero points, ...),
    graph input ranks and tensors of more than 8 dimensions. [`export`][fisheye_infer.export.exporter.export] and
    [`rebake`][fisheye_infer.export.rebake.rebake] store the report in every file's metadata (``tensorrt``).

    Args:
        model (onnx.ModelProto): The graph to check (``onnx.load("model.onnx")``).

    Returns:
        TensorRTReport: ``target`` (the TensorRT version the rules are for), ``compatible`` (no finding is an
            error) and ``findings``: ``error`` (the parser or the engine build refuses the node) or ``note``
            (accepted, but worth knowing: DOUBLE cast to FLOAT, INT64 tensors, dynamic input dimensions).

    Examples:
        ```python
        import onnx

        from fisheye_infer.export.tensorrt_check import check_tensorrt

        report = check_tensorrt(onnx.load("model.onnx"))
        print(report.compatible, report.summary())
        ```
    """
    g = GraphFacts.read(model)
    found = Findings()
    _check_opset(model, found)
    _check_inputs(g, found)
    _check_ranks(g, found)
    for graph in subgraphs(model.graph):
        for node in graph.node:
            if _check_op(node, found):
                _check_types(g, node, found)
                _check_node(g, node, found)
    note_doubles(g, found)
    note_int64(g, found)
    return TensorRTReport(
        target=TARGET, compatible=not any(f.severity == "error" for f in found), findings=tuple(found)
    )


def _check_opset(model: onnx.ModelProto, found: Findings) -> None:
    versions = [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")]
    if versions and not MIN_OPSET <= max(versions) <= MAX_OPSET:
        found.error(None, f"opset {max(versions)}: the parser imports opsets {MIN_OPSET} to {MAX_OPSET}")


def _check_ranks(g: GraphFacts, found: Findings) -> None:
    """TensorRT tensors have at most ``Dims::MAX_DIMS`` = 8 dimensions."""
    producers = {out: node for node in g.model.graph.node for out in node.output}
    for value, shape in sorted(g.shapes.items()):
        if shape is not None and len(shape) > MAX_RANK:
            node = producers.get(value)
            found.error(node, f"'{value}' has {len(shape)} dimensions: TensorRT tensors have at most {MAX_RANK}")


def _check_inputs(g: GraphFacts, found: Findings) -> None:
    for value in g.model.graph.input:
        if value.name in g.initializers:
            continue
        shape = g.shapes.get(value.name)
        if shape is None:
            found.error(None, f"graph input '{value.name}' has no known rank: a TensorRT network input needs one")
            continue
        dynamic = [i for i, d in enumerate(shape) if i > 0 and not isinstance(d, int)]
        if dynamic:
            found.note(
                None,
                f"graph input '{value.name}' has dynamic dimension(s) {dynamic} beyond the batch axis ({shape}): the "
                "engine needs an optimization profile whose min/opt/max cover them, and is tuned for that range",
            )


def _check_op(node: onnx.NodeProto, found: Findings) -> bool:
    """False when the op itself is refused (the other checks would say nothing useful)."""
    if node.domain not in ("", "ai.onnx"):
        found.error(
            node,
            f"custom op {node.domain}::{node.op_type}: the parser has no importer for it and needs a TensorRT plugin "
            "registered under that name",
        )
        return False
    if node.op_type in UNSUPPORTED_OPS:
        found.error(node, f"{node.op_type} is not supported by TensorRT's ONNX parser (operator matrix: N)")
        return False
    if node.op_type not in SUPPORTED_OPS:
        found.error(
            node, f"{node.op_type} is not in TensorRT's ONNX operator matrix: the parser has no importer for it"
        )
        return False
    return True


def _checked_values(node: onnx.NodeProto) -> list[str]:
    """The values whose element type the matrix's "Supported Types" column speaks of."""
    if node.op_type in ("If", "Loop", "Scan"):
        return []
    if node.op_type in ("Constant", "ConstantOfShape"):
        return list(node.output[:1])
    if node.op_type == "Where":
        return [n for n in node.input[1:3] if n]
    if node.op_type in ("Cast", "CastLike"):
        return [n for n in (node.input[0], node.output[0]) if n]
    return [node.input[0]] if node.input and node.input[0] else []


def _check_types(g: GraphFacts, node: onnx.NodeProto, found: Findings) -> None:
    allowed = SUPPORTED_OPS[node.op_type]
    for value in _checked_values(node):
        name = g.type_name(value)
        if name is not None and name not in allowed:
            found.error(
                node,
                f"{node.op_type} on {name} ('{value}'): TensorRT's parser supports it on {', '.join(allowed)} only",
            )
    for out in node.output:
        if out and g.types.get(out) == TensorProto.UINT8 and out not in g.outputs:
            found.error(
                node, f"'{out}' is UINT8 inside the network: TensorRT has UINT8 only as a network input or output type"
            )


def _check_node(g: GraphFacts, node: onnx.NodeProto, found: Findings) -> None:
    op = node.op_type
    for index, what in WEIGHTS_INPUTS.get(op, {}).items():
        _require_weights(g, node, index, what, found)
    if op == "TopK":
        _check_topk(g, node, found)
    elif op == "GridSample":
        _check_grid_sample(g, node, found)
    elif op == "ScatterND" and any(a.name == "reduction" for a in node.attribute):
        found.error(
            node,
            f"ScatterND with reduction='{attribute(node, 'reduction')}': the parser refuses the reduction attribute "
            "(even 'none')",
        )
    elif op == "Clip" and g.type_name(node.input[0]) in FLOAT_TYPES:
        _require_weights(g, node, 1, "min", found)
        _require_weights(g, node, 2, "max", found)
    elif op in ("MaxPool", "AveragePool", "LpPool"):
        _check_pool(node, found)
    elif op == "Resize":
        _check_resize(node, found)
    elif op == "LayerNormalization" and any(node.output[1:]):
        found.error(node, "LayerNormalization with Mean/InvStdDev outputs: the parser supports only the first output Y")
    elif op == "Squeeze" and len([n for n in node.input if n]) < 2:
        shape = g.shapes.get(node.input[0])
        if shape is None:
            found.note(
                node, "Squeeze without axes on a value of unknown shape: the parser needs its shape to be static"
            )
        elif not all(isinstance(d, int) for d in shape):
            found.error(
                node,
                f"Squeeze without axes on the dynamic shape {shape}: the parser cannot infer which axes to squeeze",
            )
    elif op in ("QuantizeLinear", "DequantizeLinear"):
        _check_zero_point(g, node, found)
    elif op == "Constant" and any(a.name in ("sparse_value", "value_string", "value_strings") for a in node.attribute):
        found.error(node, "Constant with a sparse or string value: the parser supports dense numeric values only")


def _require_weights(g: GraphFacts, node: onnx.NodeProto, index: int, what: str, found: Findings) -> None:
    if index >= len(node.input) or not node.input[index]:
        return
    value = node.input[index]
    if value in g.constants:
        return
    if value in g.derived:
        found.note(
            node,
            f"{node.op_type} {what} '{value}' is computed from constants: the parser needs it as an initializer; fold "
            "constants first",
        )
    else:
        found.error(
            node, f"{node.op_type} {what} '{value}' is computed at run time: the parser needs it as an initializer"
        )


def _check_topk(g: GraphFacts, node: onnx.NodeProto, found: Findings) -> None:
    if attribute(node, "sorted", 1) != 1:
        found.error(node, "TopK with sorted=0: the parser requires sorted=1")
    k = g.constant(node.input[1]) if len(node.input) > 1 else None
    if k is None:
        k_attr = attribute(node, "k")
        k = None if k_attr is None else np.asarray(k_attr)
    if k is None:
        found.note(
            node,
            f"TopK K '{node.input[1] if len(node.input) > 1 else ''}' is computed at run time: "
            f"TensorRT's TopK keeps at most {MAX_TOPK_K}; cannot check it here",
        )
    elif int(np.max(k)) > MAX_TOPK_K:
        found.error(node, f"TopK K={int(np.max(k))}: TensorRT's TopK layer keeps at most {MAX_TOPK_K} elements")


def _check_grid_sample(g: GraphFacts, node: onnx.NodeProto, found: Findings) -> None:
    rank = g.rank(node.input[0])
    if rank is None:
        found.note(node, "GridSample input of unknown rank: TensorRT's GridSample layer takes 4-D input only")
    elif rank != 4:
        found.error(
            node, f"GridSample on a {rank}-D input: TensorRT's GridSample layer takes 4-D input (N, C, H, W) only"
        )
    mode = attribute(node, "mode", "bilinear")
    if mode not in GRID_MODES:
        found.error(
            node,
            f"GridSample mode='{mode}': the parser knows {', '.join(GRID_MODES)} and turns any other value into "
            "nearest without an error (opset 20 renamed them 'linear'/'cubic'; export at opset 16 to 19)",
        )
    padding = attribute(node, "padding_mode", "zeros")
    if padding not in GRID_PADDING:
        found.error(node, f"GridSample padding_mode='{padding}': TensorRT supports {', '.join(GRID_PADDING)} only")


def _check_pool(node: onnx.NodeProto, found: Findings) -> None:
    if node.op_type == "MaxPool" and len(node.output) > 1:
        found.error(node, "MaxPool with an Indices output: the parser does not support it")
    kernel = attribute(node, "kernel_shape", [])
    if len(kernel) not in (2, 3):
        found.error(node, f"{node.op_type} with a {len(kernel)}-D kernel: TensorRT pools in 2-D or 3-D only")
    dilations = attribute(node, "dilations", [])
    if any(d != 1 for d in dilations):
        found.error(node, f"{node.op_type} with dilations {list(dilations)}: the parser supports dilations of 1 only")


def _check_resize(node: onnx.NodeProto, found: Findings) -> None:
    mode = attribute(node, "mode", "nearest")
    transform = attribute(node, "coordinate_transformation_mode", "half_pixel")
    if mode not in RESIZE_MODES:
        found.error(node, f"Resize mode='{mode}': the parser supports {', '.join(RESIZE_MODES)}")
    if transform not in RESIZE_TRANSFORMS:
        found.error(
            node,
            f"Resize coordinate_transformation_mode='{transform}': the parser supports {', '.join(RESIZE_TRANSFORMS)}",
        )
    if (
        transform == "tf_half_pixel_for_nn"
        and attribute(node, "nearest_mode", "round_prefer_floor") != "round_prefer_floor"
    ):
        found.error(
            node,
            "Resize tf_half_pixel_for_nn with a nearest_mode other than round_prefer_floor: not supported by the "
            "parser",
        )
    if attribute(node, "antialias", 0):
        found.error(node, "Resize with antialias=1: the parser does not support antialiasing")
    if attribute(node, "keep_aspect_ratio_policy", "stretch") != "stretch":
        found.error(node, "Resize keep_aspect_ratio_policy other than 'stretch': not supported by the parser")


def _check_zero_point(g: GraphFacts, node: onnx.NodeProto, found: Findings) -> None:
    if len(node.input) < 3 or not node.input[2]:
        return
    zero = g.constant(node.input[2])
    what = "x_zero_point" if node.op_type == "DequantizeLinear" else "y_zero_point"
    if zero is None:
        found.error(
            node, f"{node.op_type} {what} '{node.input[2]}' is not a constant: TensorRT needs a zero point of 0"
        )
    elif np.any(zero != 0):
        found.error(
            node,
            f"{node.op_type} {what} is {zero.dtype} with non-zero values: TensorRT quantizes symmetrically "
            "(zero point 0) only",
        )
