"""TensorRT's ONNX operator support matrix as data: what ``tensorrt_check`` checks a graph against.

The op types, the element types each is supported on, the inputs the importer reads as weights
and the attribute values it knows come from onnx-tensorrt's operator support matrix for TensorRT
10 (``docs/operators.md`` of the ONNX-TensorRT 10.1 GA release) and the same release's importer
(``onnxOpImporters.cpp``, ``onnxOpCheckers.cpp``). They are kept apart from the checks so that a
new TensorRT release is a change of this table, not of the logic that reads it.
"""

from __future__ import annotations

from onnx import TensorProto

__all__ = [
    "FLOAT_TYPES",
    "GRID_MODES",
    "GRID_PADDING",
    "MAX_OPSET",
    "MAX_RANK",
    "MAX_TOPK_K",
    "MIN_OPSET",
    "RESIZE_MODES",
    "RESIZE_TRANSFORMS",
    "SHAPE_ARITHMETIC",
    "SHAPE_INPUTS",
    "SUPPORTED_OPS",
    "TARGET",
    "TYPE_NAMES",
    "UNSUPPORTED_OPS",
    "WEIGHTS_INPUTS",
]

TARGET = "TensorRT 10, onnx-tensorrt 10.1 operator matrix"
MIN_OPSET, MAX_OPSET = 9, 20
MAX_TOPK_K = 3840
MAX_RANK = 8

FLOAT_TYPES = ("FP32", "FP16", "BF16")
_FI = FLOAT_TYPES + ("INT32", "INT64")
_FIB = _FI + ("BOOL",)

#: op type -> the element types the matrix lists for it (onnx-tensorrt 10.1 docs/operators.md).
SUPPORTED_OPS: dict[str, tuple[str, ...]] = {
    **dict.fromkeys(
        "Abs Add ArgMax ArgMin DepthToSpace Div Equal Greater GreaterOrEqual IsNaN Less LessOrEqual Max Min Mod Mul "
        "Neg Pad Range ReduceL1 ReduceL2 ReduceLogSum ReduceLogSumExp ReduceMax ReduceMean ReduceMin ReduceProd "
        "ReduceSum ReduceSumSquare Relu Scatter ScatterElements ScatterND Shrink Sign SpaceToDepth Sub Sum "
        "TopK".split(),
        _FI,
    ),
    **dict.fromkeys(
        "Acos Acosh Asin Asinh Atan Atanh AveragePool BatchNormalization Ceil Celu Clip Conv ConvTranspose Cos Cosh "
        "CumSum Dropout Einsum Elu Erf Exp Floor Gemm GlobalAveragePool GlobalLpPool GlobalMaxPool GroupNormalization "
        "GRU HardSigmoid HardSwish Hardmax ImageScaler InstanceNormalization IsInf LayerNormalization LeakyRelu Log "
        "LogSoftmax LRN LSTM LpNormalization LpPool MatMul MaxPool MeanVarianceNormalization ParametricSoftplus Pow "
        "PRelu QuantizeLinear RandomNormal RandomNormalLike RandomUniform RandomUniformLike Reciprocal Resize RNN "
        "Round ScaledTanh Scan Selu Sigmoid Sin Sinh Softmax Softplus Softsign Sqrt Tan Tanh ThresholdedRelu "
        "Upsample".split(),
        FLOAT_TYPES,
    ),
    **dict.fromkeys(
        "Concat Constant ConstantOfShape Expand EyeLike Flatten Gather GatherElements GatherND Identity If Loop OneHot "
        "Reshape ReverseSequence Shape Size Slice Split Squeeze Tile Transpose Trilu Unsqueeze Where".split(),
        _FIB,
    ),
    **dict.fromkeys("And Not Or Xor".split(), ("BOOL",)),
    **dict.fromkeys("Cast CastLike".split(), _FIB + ("UINT8",)),
    **dict.fromkeys("DeformConv GridSample Mish NonMaxSuppression NonZero RoiAlign".split(), ("FP32", "FP16")),
    "DequantizeLinear": ("INT8", "FP8", "INT4"),
    "Gelu": _FI + ("INT8",),
    "Mean": _FI + ("FP8",),
}

#: op types the matrix lists as not supported.
UNSUPPORTED_OPS = frozenset(
    "AffineGrid Bernoulli BitShift BitwiseAnd BitwiseNot BitwiseOr BitwiseXor BlackmanWindow Col2Im CenterCropPad "
    "Compress ConcatFromSequence ConvInteger DFT Det DynamicQuantizeLinear HammingWindow HannWindow ImageDecoder "
    "MatMulInteger MaxRoiPool MaxUnpool MelWeightMatrix Multinomial NegativeLogLikelihoodLoss Optional "
    "OptionalGetElement OptionalHasElement QLinearConv QLinearMatMul RegexFullMatch STFT SequenceAt SequenceConstruct "
    "SequenceEmpty SequenceErase SequenceInsert SequenceLength SequenceMap SoftmaxCrossEntropyLoss SplitToSequence "
    "StringConcat StringNormalizer StringSplit TfIdfVectorizer Unique".split()
)

TYPE_NAMES: dict[int, str] = {
    TensorProto.FLOAT: "FP32",
    TensorProto.FLOAT16: "FP16",
    TensorProto.BFLOAT16: "BF16",
    TensorProto.INT32: "INT32",
    TensorProto.INT64: "INT64",
    TensorProto.BOOL: "BOOL",
    TensorProto.UINT8: "UINT8",
    TensorProto.INT8: "INT8",
    TensorProto.FLOAT8E4M3FN: "FP8",
    TensorProto.INT4: "INT4",
    TensorProto.DOUBLE: "FP32",  # the parser casts DOUBLE down to FLOAT (a note says so)
}

#: Inputs the importer reads as weights (op type -> input index -> what it is), per the matrix's
#: restrictions and the importer's ``is_weights`` assertions.
WEIGHTS_INPUTS: dict[str, dict[int, str]] = {
    "CumSum": {1: "axis"},
    "Squeeze": {1: "axes"},
    "Unsqueeze": {1: "axes"},
    "Slice": {3: "axes"},
    "Pad": {3: "axes"},
    "Dropout": {2: "training_mode"},
    "OneHot": {1: "depth"},
    **{
        op: {1: "axes"}
        for op in (
            "ReduceL1",
            "ReduceL2",
            "ReduceLogSum",
            "ReduceLogSumExp",
            "ReduceMax",
            "ReduceMean",
            "ReduceMin",
            "ReduceProd",
            "ReduceSum",
            "ReduceSumSquare",
        )
    },
}

#: Inputs that hold shapes, axes or counts rather than data: INT64 there is what every exporter writes.
SHAPE_INPUTS: dict[str, frozenset[int]] = {
    "Reshape": frozenset({1}),
    "Expand": frozenset({1}),
    "Tile": frozenset({1}),
    "ConstantOfShape": frozenset({0}),
    "Slice": frozenset({1, 2, 3, 4}),
    "Unsqueeze": frozenset({1}),
    "Squeeze": frozenset({1}),
    "Pad": frozenset({1, 3}),
    "TopK": frozenset({1}),
    "Range": frozenset({0, 1, 2}),
    "Resize": frozenset({1, 2, 3}),
    "Split": frozenset({1}),
    "CumSum": frozenset({1}),
    "OneHot": frozenset({1}),
    **{
        op: frozenset({1})
        for op in (
            "ReduceL1",
            "ReduceL2",
            "ReduceLogSum",
            "ReduceLogSumExp",
            "ReduceMax",
            "ReduceMean",
            "ReduceMin",
            "ReduceProd",
            "ReduceSum",
            "ReduceSumSquare",
        )
    },
}
#: Ops that compute shapes from shapes (``Shape`` -> ``Gather`` -> ``Concat`` -> ``Reshape``).
SHAPE_ARITHMETIC = frozenset(
    "Abs Add Cast Concat Div Equal Gather Identity Max Min Mod Mul Neg ReduceProd Reshape Shape Size "
    "Slice Squeeze Sub Unsqueeze Where".split()
)

GRID_MODES = ("bilinear", "nearest", "bicubic")
GRID_PADDING = ("zeros", "border", "reflection")
RESIZE_MODES = ("nearest", "linear", "cubic")
RESIZE_TRANSFORMS = ("half_pixel", "pytorch_half_pixel", "tf_half_pixel_for_nn", "asymmetric", "align_corners")
