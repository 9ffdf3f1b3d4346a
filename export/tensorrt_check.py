"""``check_tensorrt``: would TensorRT's ONNX parser take this graph? A static check; no TensorRT needed.

    report = check_tensorrt(onnx.load("model.onnx"))   # TensorRTReport: compatible, findings

A file that ONNX Runtime runs on a CPU can still be refused by a GPU runtime: TensorRT imports
ONNX through its own parser, which supports fewer operators, attribute values and data types.
Finding that out at export costs milliseconds; finding it on the robot costs a rebuild. The
rules come from onnx-tensorrt's operator support matrix for TensorRT 10
(``docs/operators.md`` of the ONNX-TensorRT 10.1 GA release: "TensorRT 10.0 supports operators
in the inclusive range of opset 9 to opset 20"), and where the matrix is terse, from the same
release's importer (``onnxOpImporters.cpp``, ``onnxOpCheckers.cpp``), which is what refuses a node:

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
TensorRT 8.x cast down to INT32, clamping; dynamic input dimensions beyond the batch axis (the
engine needs an optimization profile covering them); a weights-only input computed from
constants (fold constants first); a TopK K computed at run time (cannot be checked here).
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
import onnx
from onnx import TensorProto, numpy_helper

from fisheye_infer.artifact import TensorRTFinding, TensorRTReport

__all__ = ["MAX_OPSET", "MAX_RANK", "MAX_TOPK_K", "MIN_OPSET", "SUPPORTED_OPS", "TARGET", "UNSUPPORTED_OPS", "check_tensorrt"]

TARGET = "TensorRT 10, onnx-tensorrt 10.1 operator matrix"
MIN_OPSET, MAX_OPSET = 9, 20
MAX_TOPK_K = 3840
MAX_RANK = 8

_F = ("FP32", "FP16", "BF16")
_FI = _F + ("INT32", "INT64")
_FIB = _FI + ("BOOL",)

#: op type -> the element types the matrix lists for it (onnx-tensorrt 10.1 docs/operators.md).
SUPPORTED_OPS: dict[str, tuple[str, ...]] = {
    **dict.fromkeys(
        "Abs Add ArgMax ArgMin DepthToSpace Div Equal Greater GreaterOrEqual IsNaN Less LessOrEqual Max Min Mod Mul Neg Pad "
        "Range ReduceL1 ReduceL2 ReduceLogSum ReduceLogSumExp ReduceMax ReduceMean ReduceMin ReduceProd ReduceSum "
        "ReduceSumSquare Relu Scatter ScatterElements ScatterND Shrink Sign SpaceToDepth Sub Sum TopK".split(), _FI),
    **dict.fromkeys(
        "Acos Acosh Asin Asinh Atan Atanh AveragePool BatchNormalization Ceil Celu Clip Conv ConvTranspose Cos Cosh CumSum "
        "Dropout Einsum Elu Erf Exp Floor Gemm GlobalAveragePool GlobalLpPool GlobalMaxPool GroupNormalization GRU HardSigmoid "
        "HardSwish Hardmax ImageScaler InstanceNormalization IsInf LayerNormalization LeakyRelu Log LogSoftmax LRN LSTM "
        "LpNormalization LpPool MatMul MaxPool MeanVarianceNormalization ParametricSoftplus Pow PRelu QuantizeLinear RandomNormal "
        "RandomNormalLike RandomUniform RandomUniformLike Reciprocal Resize RNN Round ScaledTanh Scan Selu Sigmoid Sin Sinh "
        "Softmax Softplus Softsign Sqrt Tan Tanh ThresholdedRelu Upsample".split(), _F),
    **dict.fromkeys(
        "Concat Constant ConstantOfShape Expand EyeLike Flatten Gather GatherElements GatherND Identity If Loop OneHot Reshape "
        "ReverseSequence Shape Size Slice Split Squeeze Tile Transpose Trilu Unsqueeze Where".split(), _FIB),
    **dict.fromkeys("And Not Or Xor".split(), ("BOOL",)),
    **dict.fromkeys("Cast CastLike".split(), _FIB + ("UINT8",)),
    **dict.fromkeys("DeformConv GridSample Mish NonMaxSuppression NonZero RoiAlign".split(), ("FP32", "FP16")),
    "DequantizeLinear": ("INT8", "FP8", "INT4"),
    "Gelu": _FI + ("INT8",),
    "Mean": _FI + ("FP8",),
}

#: op types the matrix lists as not supported.
UNSUPPORTED_OPS = frozenset(
    "AffineGrid Bernoulli BitShift BitwiseAnd BitwiseNot BitwiseOr BitwiseXor BlackmanWindow Col2Im CenterCropPad Compress "
    "ConcatFromSequence ConvInteger DFT Det DynamicQuantizeLinear HammingWindow HannWindow ImageDecoder MatMulInteger MaxRoiPool "
    "MaxUnpool MelWeightMatrix Multinomial NegativeLogLikelihoodLoss Optional OptionalGetElement OptionalHasElement QLinearConv "
    "QLinearMatMul RegexFullMatch STFT SequenceAt SequenceConstruct SequenceEmpty SequenceErase SequenceInsert SequenceLength "
    "SequenceMap SoftmaxCrossEntropyLoss SplitToSequence StringConcat StringNormalizer StringSplit TfIdfVectorizer Unique".split())

_TYPE_NAMES = {
    TensorProto.FLOAT: "FP32", TensorProto.FLOAT16: "FP16", TensorProto.BFLOAT16: "BF16", TensorProto.INT32: "INT32",
    TensorProto.INT64: "INT64", TensorProto.BOOL: "BOOL", TensorProto.UINT8: "UINT8", TensorProto.INT8: "INT8",
    TensorProto.FLOAT8E4M3FN: "FP8", TensorProto.INT4: "INT4",
    TensorProto.DOUBLE: "FP32",  # the parser casts DOUBLE down to FLOAT (a note says so)
}

#: Inputs the importer reads as weights (op type -> input index -> what it is), per the matrix's
#: restrictions and the importer's ``is_weights`` assertions.
_WEIGHTS_INPUTS: dict[str, dict[int, str]] = {
    "CumSum": {1: "axis"},
    "Squeeze": {1: "axes"},
    "Unsqueeze": {1: "axes"},
    "Slice": {3: "axes"},
    "Pad": {3: "axes"},
    "Dropout": {2: "training_mode"},
    "OneHot": {1: "depth"},
    **{op: {1: "axes"} for op in ("ReduceL1", "ReduceL2", "ReduceLogSum", "ReduceLogSumExp", "ReduceMax", "ReduceMean",
                                  "ReduceMin", "ReduceProd", "ReduceSum", "ReduceSumSquare")},
}

#: Inputs that hold shapes, axes or counts rather than data: INT64 there is what every exporter writes.
_SHAPE_INPUTS: dict[str, frozenset[int]] = {
    "Reshape": frozenset({1}), "Expand": frozenset({1}), "Tile": frozenset({1}), "ConstantOfShape": frozenset({0}),
    "Slice": frozenset({1, 2, 3, 4}), "Unsqueeze": frozenset({1}), "Squeeze": frozenset({1}), "Pad": frozenset({1, 3}),
    "TopK": frozenset({1}), "Range": frozenset({0, 1, 2}), "Resize": frozenset({1, 2, 3}), "Split": frozenset({1}),
    "CumSum": frozenset({1}), "OneHot": frozenset({1}),
    **{op: frozenset({1}) for op in ("ReduceL1", "ReduceL2", "ReduceLogSum", "ReduceLogSumExp", "ReduceMax", "ReduceMean",
                                     "ReduceMin", "ReduceProd", "ReduceSum", "ReduceSumSquare")},
}
#: Ops that compute shapes from shapes (``Shape`` -> ``Gather`` -> ``Concat`` -> ``Reshape``).
_SHAPE_ARITHMETIC = frozenset("Abs Add Cast Concat Div Equal Gather Identity Max Min Mod Mul Neg ReduceProd Reshape Shape Size "
                              "Slice Squeeze Sub Unsqueeze Where".split())

_GRID_MODES = ("bilinear", "nearest", "bicubic")
_GRID_PADDING = ("zeros", "border", "reflection")
_RESIZE_MODES = ("nearest", "linear", "cubic")
_RESIZE_TRANSFORMS = ("half_pixel", "pytorch_half_pixel", "tf_half_pixel_for_nn", "asymmetric", "align_corners")
_INT32 = np.iinfo(np.int32)
_EXAMPLES = 3


@dataclass
class _Graph:
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
    def read(cls, model: onnx.ModelProto) -> _Graph:
        try:
            inferred = onnx.shape_inference.infer_shapes(model, strict_mode=False)
        except Exception:  # inference is best effort: the checks that need types skip unknown ones
            inferred = model
        g = cls(model)
        for graph in _graphs(inferred.graph):
            for value in list(graph.value_info) + list(graph.input) + list(graph.output):
                t = value.type.tensor_type
                if t.elem_type:
                    g.types[value.name] = t.elem_type
                g.shapes[value.name] = [d.dim_value if d.HasField("dim_value") else (d.dim_param or None) for d in t.shape.dim] if t.HasField("shape") else None
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
            elif node.op_type != "Shape" and node.input and all(not n or n in g.constants or n in g.derived for n in node.input):
                g.derived.update(node.output)
        return g

    def type_name(self, value: str) -> str | None:
        elem = self.types.get(value)
        return None if elem is None else _TYPE_NAMES.get(elem, TensorProto.DataType.Name(elem))

    def rank(self, value: str) -> int | None:
        shape = self.shapes.get(value)
        return None if shape is None else len(shape)

    def constant(self, value: str) -> np.ndarray | None:
        tensor = self.constants.get(value)
        return None if tensor is None else numpy_helper.to_array(tensor)


def _graphs(graph: onnx.GraphProto) -> Iterator[onnx.GraphProto]:
    """``graph`` and every subgraph of its nodes (If, Loop, Scan bodies), depth first."""
    yield graph
    for node in graph.node:
        for attr in node.attribute:
            for sub in [attr.g] if attr.HasField("g") else list(attr.graphs):
                yield from _graphs(sub)


def _attr(node: onnx.NodeProto, name: str, default: object = None) -> object:
    for a in node.attribute:
        if a.name == name:
            value = onnx.helper.get_attribute_value(a)
            return value.decode() if isinstance(value, bytes) else value
    return default


class _Findings(list):
    def error(self, node: onnx.NodeProto | None, message: str) -> None:
        self.append(TensorRTFinding(severity="error", node=node.name if node else "", op_type=node.op_type if node else "", message=message))

    def note(self, node: onnx.NodeProto | None, message: str) -> None:
        self.append(TensorRTFinding(severity="note", node=node.name if node else "", op_type=node.op_type if node else "", message=message))


def check_tensorrt(model: onnx.ModelProto) -> TensorRTReport:
    """The findings of every check in the module docstring on ``model``; ``compatible`` when none is an error."""
    g = _Graph.read(model)
    found = _Findings()
    _check_opset(model, found)
    _check_inputs(g, found)
    _check_ranks(g, found)
    for graph in _graphs(model.graph):
        for node in graph.node:
            if _check_op(node, found):
                _check_types(g, node, found)
                _check_node(g, node, found)
    _note_doubles(g, found)
    _note_int64(g, found)
    return TensorRTReport(target=TARGET, compatible=not any(f.severity == "error" for f in found), findings=tuple(found))


def _check_opset(model: onnx.ModelProto, found: _Findings) -> None:
    versions = [o.version for o in model.opset_import if o.domain in ("", "ai.onnx")]
    if versions and not MIN_OPSET <= max(versions) <= MAX_OPSET:
        found.error(None, f"opset {max(versions)}: the parser imports opsets {MIN_OPSET} to {MAX_OPSET}")


def _check_ranks(g: _Graph, found: _Findings) -> None:
    """TensorRT tensors have at most ``Dims::MAX_DIMS`` = 8 dimensions."""
    producers = {out: node for node in g.model.graph.node for out in node.output}
    for value, shape in sorted(g.shapes.items()):
        if shape is not None and len(shape) > MAX_RANK:
            node = producers.get(value)
            found.error(node, f"'{value}' has {len(shape)} dimensions: TensorRT tensors have at most {MAX_RANK}")


def _check_inputs(g: _Graph, found: _Findings) -> None:
    for value in g.model.graph.input:
        if value.name in g.initializers:
            continue
        shape = g.shapes.get(value.name)
        if shape is None:
            found.error(None, f"graph input '{value.name}' has no known rank: a TensorRT network input needs one")
            continue
        dynamic = [i for i, d in enumerate(shape) if i > 0 and not isinstance(d, int)]
        if dynamic:
            found.note(None, f"graph input '{value.name}' has dynamic dimension(s) {dynamic} beyond the batch axis "
                             f"({shape}): the engine needs an optimization profile whose min/opt/max cover them, and is tuned for that range")


def _check_op(node: onnx.NodeProto, found: _Findings) -> bool:
    """False when the op itself is refused (the other checks would say nothing useful)."""
    if node.domain not in ("", "ai.onnx"):
        found.error(node, f"custom op {node.domain}::{node.op_type}: the parser has no importer for it and needs a TensorRT plugin registered under that name")
        return False
    if node.op_type in UNSUPPORTED_OPS:
        found.error(node, f"{node.op_type} is not supported by TensorRT's ONNX parser (operator matrix: N)")
        return False
    if node.op_type not in SUPPORTED_OPS:
        found.error(node, f"{node.op_type} is not in TensorRT's ONNX operator matrix: the parser has no importer for it")
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


def _check_types(g: _Graph, node: onnx.NodeProto, found: _Findings) -> None:
    allowed = SUPPORTED_OPS[node.op_type]
    for value in _checked_values(node):
        name = g.type_name(value)
        if name is not None and name not in allowed:
            found.error(node, f"{node.op_type} on {name} ('{value}'): TensorRT's parser supports it on {', '.join(allowed)} only")
    for out in node.output:
        if out and g.types.get(out) == TensorProto.UINT8 and out not in g.outputs:
            found.error(node, f"'{out}' is UINT8 inside the network: TensorRT has UINT8 only as a network input or output type")


def _check_node(g: _Graph, node: onnx.NodeProto, found: _Findings) -> None:
    op = node.op_type
    for index, what in _WEIGHTS_INPUTS.get(op, {}).items():
        _require_weights(g, node, index, what, found)
    if op == "TopK":
        _check_topk(g, node, found)
    elif op == "GridSample":
        _check_grid_sample(g, node, found)
    elif op == "ScatterND" and any(a.name == "reduction" for a in node.attribute):
        found.error(node, f"ScatterND with reduction='{_attr(node, 'reduction')}': the parser refuses the reduction attribute (even 'none')")
    elif op == "Clip" and g.type_name(node.input[0]) in _F:
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
            found.note(node, "Squeeze without axes on a value of unknown shape: the parser needs its shape to be static")
        elif not all(isinstance(d, int) for d in shape):
            found.error(node, f"Squeeze without axes on the dynamic shape {shape}: the parser cannot infer which axes to squeeze")
    elif op in ("QuantizeLinear", "DequantizeLinear"):
        _check_zero_point(g, node, found)
    elif op == "Constant" and any(a.name in ("sparse_value", "value_string", "value_strings") for a in node.attribute):
        found.error(node, "Constant with a sparse or string value: the parser supports dense numeric values only")


def _require_weights(g: _Graph, node: onnx.NodeProto, index: int, what: str, found: _Findings) -> None:
    if index >= len(node.input) or not node.input[index]:
        return
    value = node.input[index]
    if value in g.constants:
        return
    if value in g.derived:
        found.note(node, f"{node.op_type} {what} '{value}' is computed from constants: the parser needs it as an initializer; fold constants first")
    else:
        found.error(node, f"{node.op_type} {what} '{value}' is computed at run time: the parser needs it as an initializer")


def _check_topk(g: _Graph, node: onnx.NodeProto, found: _Findings) -> None:
    if _attr(node, "sorted", 1) != 1:
        found.error(node, "TopK with sorted=0: the parser requires sorted=1")
    k = g.constant(node.input[1]) if len(node.input) > 1 else None
    if k is None:
        k_attr = _attr(node, "k")
        k = None if k_attr is None else np.asarray(k_attr)
    if k is None:
        found.note(node, f"TopK K '{node.input[1] if len(node.input) > 1 else ''}' is computed at run time: "
                         f"TensorRT's TopK keeps at most {MAX_TOPK_K}; cannot check it here")
    elif int(np.max(k)) > MAX_TOPK_K:
        found.error(node, f"TopK K={int(np.max(k))}: TensorRT's TopK layer keeps at most {MAX_TOPK_K} elements")


def _check_grid_sample(g: _Graph, node: onnx.NodeProto, found: _Findings) -> None:
    rank = g.rank(node.input[0])
    if rank is None:
        found.note(node, "GridSample input of unknown rank: TensorRT's GridSample layer takes 4-D input only")
    elif rank != 4:
        found.error(node, f"GridSample on a {rank}-D input: TensorRT's GridSample layer takes 4-D input (N, C, H, W) only")
    mode = _attr(node, "mode", "bilinear")
    if mode not in _GRID_MODES:
        found.error(node, f"GridSample mode='{mode}': the parser knows {', '.join(_GRID_MODES)} and turns any other value into nearest "
                          f"without an error (opset 20 renamed them 'linear'/'cubic'; export at opset 16 to 19)")
    padding = _attr(node, "padding_mode", "zeros")
    if padding not in _GRID_PADDING:
        found.error(node, f"GridSample padding_mode='{padding}': TensorRT supports {', '.join(_GRID_PADDING)} only")


def _check_pool(node: onnx.NodeProto, found: _Findings) -> None:
    if node.op_type == "MaxPool" and len(node.output) > 1:
        found.error(node, "MaxPool with an Indices output: the parser does not support it")
    kernel = _attr(node, "kernel_shape", [])
    if len(kernel) not in (2, 3):
        found.error(node, f"{node.op_type} with a {len(kernel)}-D kernel: TensorRT pools in 2-D or 3-D only")
    dilations = _attr(node, "dilations", [])
    if any(d != 1 for d in dilations):
        found.error(node, f"{node.op_type} with dilations {list(dilations)}: the parser supports dilations of 1 only")


def _check_resize(node: onnx.NodeProto, found: _Findings) -> None:
    mode = _attr(node, "mode", "nearest")
    transform = _attr(node, "coordinate_transformation_mode", "half_pixel")
    if mode not in _RESIZE_MODES:
        found.error(node, f"Resize mode='{mode}': the parser supports {', '.join(_RESIZE_MODES)}")
    if transform not in _RESIZE_TRANSFORMS:
        found.error(node, f"Resize coordinate_transformation_mode='{transform}': the parser supports {', '.join(_RESIZE_TRANSFORMS)}")
    if transform == "tf_half_pixel_for_nn" and _attr(node, "nearest_mode", "round_prefer_floor") != "round_prefer_floor":
        found.error(node, "Resize tf_half_pixel_for_nn with a nearest_mode other than round_prefer_floor: not supported by the parser")
    if _attr(node, "antialias", 0):
        found.error(node, "Resize with antialias=1: the parser does not support antialiasing")
    if _attr(node, "keep_aspect_ratio_policy", "stretch") != "stretch":
        found.error(node, "Resize keep_aspect_ratio_policy other than 'stretch': not supported by the parser")


def _check_zero_point(g: _Graph, node: onnx.NodeProto, found: _Findings) -> None:
    if len(node.input) < 3 or not node.input[2]:
        return
    zero = g.constant(node.input[2])
    what = "x_zero_point" if node.op_type == "DequantizeLinear" else "y_zero_point"
    if zero is None:
        found.error(node, f"{node.op_type} {what} '{node.input[2]}' is not a constant: TensorRT needs a zero point of 0")
    elif np.any(zero != 0):
        found.error(node, f"{node.op_type} {what} is {zero.dtype} with non-zero values: TensorRT quantizes symmetrically (zero point 0) only")


def _note_doubles(g: _Graph, found: _Findings) -> None:
    doubles = sorted(v for v, t in g.types.items() if t == TensorProto.DOUBLE)
    if doubles:
        found.note(None, f"{len(doubles)} DOUBLE value(s) (e.g. {', '.join(doubles[:_EXAMPLES])}): the parser casts DOUBLE down to FLOAT, "
                         "clamping to +-FLT_MAX")


def _shape_like(g: _Graph) -> set[str]:
    """Values that only ever hold shapes, axes or counts: every use is a shape input, or shape arithmetic
    whose results are shape-like too. Graph outputs never are."""
    graph = g.model.graph
    uses: dict[str, list[tuple[onnx.NodeProto, int]]] = {}
    for node in graph.node:
        for i, name in enumerate(node.input):
            uses.setdefault(name, []).append((node, i))
    for sub in list(_graphs(graph))[1:]:  # a value read inside a subgraph: treat as data
        for node in sub.node:
            for name in node.input:
                uses.setdefault(name, []).append((node, -1))
    shape_like: set[str] = set()

    def decide(value: str) -> None:
        if value in g.outputs or not uses.get(value):
            return
        if all(i in _SHAPE_INPUTS.get(n.op_type, ()) or (n.op_type in _SHAPE_ARITHMETIC and all(o in shape_like for o in n.output if o))
               for n, i in uses[value]):
            shape_like.add(value)

    for node in reversed(graph.node):  # consumers before producers
        for out in node.output:
            decide(out)
    for name in list(g.initializers) + list(g.inputs):
        decide(name)
    return shape_like


def _note_int64(g: _Graph, found: _Findings) -> None:
    shape_like = _shape_like(g)
    tables = sorted((i for name, i in g.initializers.items() if i.data_type == TensorProto.INT64 and name not in shape_like),
                    key=lambda t: -int(np.prod(t.dims, dtype=np.int64)))  # the largest tables make the best examples
    if tables:
        arrays = [numpy_helper.to_array(t) for t in tables]
        largest = max((int(np.abs(a).max()) for a in arrays if a.size), default=0)
        fits = all(a.size == 0 or (a.min() >= _INT32.min and a.max() <= _INT32.max) for a in arrays)
        examples = ", ".join(f"{t.name} {tuple(t.dims)}" for t in tables[:_EXAMPLES])
        found.note(None, f"{len(tables)} INT64 initializer(s) hold data, not shapes (e.g. {examples}): TensorRT 10 keeps INT64 "
                         f"for the ops the matrix lists it for; TensorRT 8.x casts INT64 down to INT32, clamping to +-2^31-1: "
                         + (f"every value fits in INT32 (largest |value| {largest})" if fits else f"values up to {largest} do NOT fit in INT32"))
    values = [(node, out) for node in g.model.graph.node for out in node.output
              if out and g.types.get(out) == TensorProto.INT64 and out not in shape_like]
    if values:
        examples = ", ".join(f"{out} ({node.op_type})" for node, out in values[:_EXAMPLES])
        found.note(None, f"{len(values)} INT64 value(s) computed at run time hold data, not shapes (e.g. {examples}): TensorRT 10 "
                         "computes them in INT64; TensorRT 8.x computes them in INT32")
