"""The int8 rewrites compute what the graph computed: hand-made graphs, run in ONNX Runtime before and after."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from fisheye_infer.export.int8_rewrites import stem_as_space_to_depth, upsample_as_depth_to_space
from fisheye_infer.export.quantized_rewrites import data_movement_on_quantized_values, neighbour_swap_as_concat

RNG = np.random.default_rng(0)


def _model(
    nodes: list[onnx.NodeProto], inputs: list[onnx.ValueInfoProto], inits: dict[str, np.ndarray]
) -> onnx.ModelProto:
    graph = helper.make_graph(
        nodes,
        "g",
        inputs,
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)],
        [numpy_helper.from_array(v, k) for k, v in inits.items()],
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


def _run(model: onnx.ModelProto, feeds: dict[str, np.ndarray]) -> np.ndarray:
    known = {i.name for i in model.graph.input} | {i.name for i in model.graph.initializer}
    for node in model.graph.node:  # in graph order: every value made before it is read
        assert set(node.input) <= known, f"{node.name} reads {set(node.input) - known} before it is made"
        known.update(node.output)
    options = ort.SessionOptions()
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    return ort.InferenceSession(model.SerializeToString(), options, providers=["CPUExecutionProvider"]).run(
        None, feeds
    )[0]


def _ops(model: onnx.ModelProto) -> list[str]:
    return [n.op_type for n in model.graph.node]


# -- the stem as a convolution over 2 x 2 blocks ------------------------------------------------------


def _stem(k: int, pad: int, channels: int = 3, size: tuple[int, int] = (20, 16), bias: bool = True) -> onnx.ModelProto:
    inits = {"w": RNG.normal(size=(8, channels, k, k)).astype(np.float32)}
    if bias:
        inits["b"] = RNG.normal(size=8).astype(np.float32)
    nodes = [
        helper.make_node("Transpose", ["x"], ["t"], perm=[0, 3, 1, 2]),
        helper.make_node(
            "Conv", ["t", *inits], ["y"], name="stem", kernel_shape=[k, k], strides=[2, 2], pads=[pad] * 4
        ),
    ]
    return _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, ["n", *size, channels])], inits)


@pytest.mark.parametrize(("k", "pad"), [(7, 3), (3, 1), (5, 2), (4, 0), (3, 0)])
def test_stem_over_blocks_gives_the_same_output(k: int, pad: int) -> None:
    model = _stem(k, pad)
    x = {"x": RNG.normal(size=(2, 20, 16, 3)).astype(np.float32)}
    before = _run(model, x)
    assert stem_as_space_to_depth(model) == ["stem"]
    conv = next(n for n in model.graph.node if n.op_type == "Conv")
    assert [a.ints for a in conv.attribute if a.name == "strides"] == [[1, 1]]
    assert list({i.name: i for i in model.graph.initializer}["w"].dims[:2]) == [8, 12]  # 4 x 3 channels
    after = _run(model, x)
    assert after.shape == before.shape
    np.testing.assert_allclose(after, before, rtol=1e-5, atol=1e-4)


def test_stem_not_named_is_left_alone() -> None:
    model = _stem(7, 3)
    assert stem_as_space_to_depth(model, only=["another"]) == []
    assert _ops(model) == ["Transpose", "Conv"]


@pytest.mark.parametrize(
    ("change", "why"),
    [
        ({"size": (21, 16)}, "odd height"),
        ({"channels": 8}, "more channels than a stem"),
    ],
)
def test_stem_left_alone_where_the_blocks_do_not_fit(change: dict, why: str) -> None:
    model = _stem(7, 3, **change)
    assert stem_as_space_to_depth(model) == [], why


def test_stem_left_alone_at_stride_one() -> None:
    model = _stem(3, 1)
    conv = next(n for n in model.graph.node if n.op_type == "Conv")
    conv.attribute.remove(next(a for a in conv.attribute if a.name == "strides"))
    conv.attribute.append(helper.make_attribute("strides", [1, 1]))
    assert stem_as_space_to_depth(model) == []


# -- ConvTranspose (kernel = stride) as Conv + DepthToSpace ---------------------------------------------


def _upsample(k: int, stride: int, relu: bool, bias: bool = True) -> onnx.ModelProto:
    inits = {"w": RNG.normal(size=(6, 5, k, k)).astype(np.float32)}
    if bias:
        inits["b"] = RNG.normal(size=5).astype(np.float32)
    nodes = [
        helper.make_node(
            "ConvTranspose",
            ["x", *inits],
            ["u" if relu else "y"],
            name="up",
            kernel_shape=[k, k],
            strides=[stride, stride],
        )
    ]
    if relu:
        nodes.append(helper.make_node("Relu", ["u"], ["y"], name="relu"))
    return _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 6, 7, 9])], inits)


@pytest.mark.parametrize(("k", "relu", "bias"), [(2, True, True), (2, False, True), (3, True, False)])
def test_upsample_as_depth_to_space_gives_the_same_output(k: int, relu: bool, bias: bool) -> None:
    model = _upsample(k, k, relu, bias)
    x = {"x": RNG.normal(size=(1, 6, 7, 9)).astype(np.float32)}
    before = _run(model, x)
    assert upsample_as_depth_to_space(model) == ["up"]
    assert _ops(model) == ["Conv", "Relu", "DepthToSpace"] if relu else ["Conv", "DepthToSpace"]
    np.testing.assert_allclose(_run(model, x), before, rtol=1e-5, atol=1e-5)


def test_overlapping_upsample_is_left_alone() -> None:
    model = _upsample(3, 2, relu=False)
    assert upsample_as_depth_to_space(model) == []
    assert _ops(model) == ["ConvTranspose"]


# -- data movement on the uint8 side of per-tensor (de)quantization ------------------------------------


def _scalars(scale: float = 0.05, zero: int = 128) -> dict[str, np.ndarray]:
    return {"s": np.array(scale, np.float32), "z": np.array(zero, np.uint8)}


def test_depth_to_space_moves_before_the_dequantization() -> None:
    nodes = [
        helper.make_node("QuantizeLinear", ["x", "s", "z"], ["q"]),
        helper.make_node("DequantizeLinear", ["q", "s", "z"], ["d"]),
        helper.make_node("DepthToSpace", ["d"], ["y"], name="d2s", blocksize=2, mode="CRD"),
    ]
    model = _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 8, 3, 5])], _scalars())
    x = {"x": RNG.normal(size=(1, 8, 3, 5)).astype(np.float32)}
    before = _run(model, x)
    assert data_movement_on_quantized_values(model) == ["d2s"]
    assert _ops(model) == ["QuantizeLinear", "DepthToSpace", "DequantizeLinear"]
    np.testing.assert_array_equal(_run(model, x), before)


def test_quantization_moves_to_the_start_of_a_reshape_transpose_chain() -> None:
    nodes = [
        helper.make_node("Relu", ["x"], ["r"]),
        helper.make_node("Reshape", ["r", "shape"], ["a"], name="split"),
        helper.make_node("Transpose", ["a"], ["b"], name="swap", perm=[0, 2, 1, 3]),
        helper.make_node("QuantizeLinear", ["b", "s", "z"], ["q"]),
        helper.make_node("DequantizeLinear", ["q", "s", "z"], ["y"]),
    ]
    inits = {**_scalars(), "shape": np.array([2, 3, 4, 5], np.int64)}
    model = _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2, 12, 5])], inits)
    x = {"x": RNG.normal(size=(2, 12, 5)).astype(np.float32)}
    before = _run(model, x)
    assert data_movement_on_quantized_values(model) == ["split", "swap"]
    assert _ops(model) == ["Relu", "QuantizeLinear", "Reshape", "Transpose", "DequantizeLinear"]
    np.testing.assert_array_equal(_run(model, x), before)


def test_per_channel_quantization_is_left_alone() -> None:
    """A per-channel scale is not the same for every value: permuting across channels would change it."""
    nodes = [
        helper.make_node("QuantizeLinear", ["x", "s", "z"], ["q"], axis=1),
        helper.make_node("DequantizeLinear", ["q", "s", "z"], ["d"], axis=1),
        helper.make_node("DepthToSpace", ["d"], ["y"], blocksize=2, mode="CRD"),
    ]
    inits = {"s": np.full(8, 0.05, np.float32), "z": np.full(8, 128, np.uint8)}
    model = _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 8, 3, 5])], inits)
    assert data_movement_on_quantized_values(model) == []
    assert _ops(model) == ["QuantizeLinear", "DequantizeLinear", "DepthToSpace"]


def test_a_value_with_a_second_reader_stays_float() -> None:
    nodes = [
        helper.make_node("Transpose", ["x"], ["t"], perm=[0, 2, 1]),
        helper.make_node("QuantizeLinear", ["t", "s", "z"], ["q"]),
        helper.make_node("DequantizeLinear", ["q", "s", "z"], ["d"]),
        helper.make_node("Add", ["d", "t"], ["y"]),
    ]
    model = _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4, 6])], _scalars())
    assert data_movement_on_quantized_values(model) == []


def test_two_chains_from_one_value_get_their_own_quantized_values() -> None:
    nodes = [
        helper.make_node("Relu", ["x"], ["r"]),
        helper.make_node("Transpose", ["r"], ["a"], name="swap", perm=[0, 2, 1]),
        helper.make_node("QuantizeLinear", ["a", "s", "z"], ["qa"]),
        helper.make_node("DequantizeLinear", ["qa", "s", "z"], ["da"]),
        helper.make_node("Reshape", ["r", "shape"], ["b"], name="flat"),
        helper.make_node("QuantizeLinear", ["b", "s", "z"], ["qb"]),
        helper.make_node("DequantizeLinear", ["qb", "s", "z"], ["db"]),
        helper.make_node("Reshape", ["db", "back"], ["db3"]),
        helper.make_node("Transpose", ["da"], ["da3"], perm=[0, 2, 1]),
        helper.make_node("Add", ["db3", "da3"], ["y"]),
    ]
    inits = {**_scalars(), "shape": np.array([2, 12], np.int64), "back": np.array([2, 3, 4], np.int64)}
    model = _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [2, 3, 4])], inits)
    x = {"x": RNG.normal(size=(2, 3, 4)).astype(np.float32)}
    before = _run(model, x)
    assert sorted(data_movement_on_quantized_values(model)) == ["flat", "swap"]
    outputs = [o for n in model.graph.node for o in n.output]
    assert len(outputs) == len(set(outputs))
    np.testing.assert_array_equal(_run(model, x), before)


def test_moves_in_a_row_do_not_reuse_a_name() -> None:
    """A DepthToSpace moved before its DequantizeLinear, then a chain after that ending in a QuantizeLinear."""
    nodes = [
        helper.make_node("QuantizeLinear", ["x", "s", "z"], ["q"]),
        helper.make_node("DequantizeLinear", ["q", "s", "z"], ["d"]),
        helper.make_node("DepthToSpace", ["d"], ["e"], name="d2s", blocksize=2, mode="CRD"),
        helper.make_node("Transpose", ["e"], ["t"], name="swap", perm=[0, 1, 3, 2]),
        helper.make_node("QuantizeLinear", ["t", "s", "z"], ["q2"]),
        helper.make_node("DequantizeLinear", ["q2", "s", "z"], ["y"]),
    ]
    model = _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 8, 3, 5])], _scalars())
    x = {"x": RNG.normal(size=(1, 8, 3, 5)).astype(np.float32)}
    before = _run(model, x)
    assert data_movement_on_quantized_values(model) == ["d2s", "swap"]
    outputs = [o for n in model.graph.node for o in n.output]
    assert len(outputs) == len(set(outputs))
    np.testing.assert_array_equal(_run(model, x), before)


# -- a neighbouring-axes swap as Split + Concat ----------------------------------------------------


def _swap(shape: list[int | str], axis: int, elem: int = TensorProto.UINT8) -> onnx.ModelProto:
    perm = list(range(len(shape)))
    perm[axis], perm[axis + 1] = axis + 1, axis
    graph = helper.make_graph(
        [helper.make_node("Transpose", ["x"], ["y"], name="swap", perm=perm)],
        "g",
        [helper.make_tensor_value_info("x", elem, shape)],
        [helper.make_tensor_value_info("y", elem, None)],
    )
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


@pytest.mark.parametrize(
    ("shape", "axis"),
    [
        (["n", 40, 2, 400, 2, 3], 2),  # the stem's 2x2 blocks: the rows of a block before the block's column
        (["n", 3, 300, 80], 1),  # three slices, runs of 80 values
        ([2, 4, 20000, 2], 1),  # a known batch, runs of two values
    ],
)
def test_neighbour_swap_as_concat_gives_the_same_values(shape: list[int | str], axis: int) -> None:
    model = _swap(shape, axis)
    x = {"x": RNG.integers(0, 256, [2 if d == "n" else d for d in shape], dtype=np.uint8)}
    before = _run(model, x)
    assert neighbour_swap_as_concat(model) == ["swap"]
    ops = _ops(model)
    assert "Transpose" not in ops and ops[0] == "Split" and ops[-1] == "Concat" and ops.count("Reshape") == shape[axis]
    assert model.graph.node[-1].output[0] == "y"  # the graph's output keeps its name
    np.testing.assert_array_equal(_run(model, x), before)


@pytest.mark.parametrize(
    ("shape", "axis", "elem", "why"),
    [
        (["n", 40, 8, 400, 6], 2, TensorProto.UINT8, "eight slices: more than SWAP_MAX_SLICES"),
        (["n", 4, 100, 16], 1, TensorProto.UINT8, "6,400 values a batch item: Transpose is as fast"),
        (["n", 400, 2, "w", 200], 2, TensorProto.UINT8, "a dimension after the swap is unknown"),
        ([2, 4, 40000], 1, TensorProto.UINT8, "runs of one value: Concat is slower"),
        ([2, 300, 300], 0, TensorProto.UINT8, "the batch axis"),
        (["n", 40, 2, 400, 2, 3], 2, TensorProto.FLOAT, "float: ONNX Runtime's Transpose is as fast"),
    ],
)
def test_neighbour_swap_left_alone(shape: list[int | str], axis: int, elem: int, why: str) -> None:
    model = _swap(shape, axis, elem)
    assert neighbour_swap_as_concat(model) == [], why
    assert _ops(model) == ["Transpose"]


@pytest.mark.parametrize("perm", [[0, 3, 2, 1], [0, 2, 3, 1]])
def test_other_permutations_are_left_alone(perm: list[int]) -> None:
    """Two axes exchanged that are not neighbours, and a rotation of three."""
    graph = helper.make_graph(
        [helper.make_node("Transpose", ["x"], ["y"], perm=perm)],
        "g",
        [helper.make_tensor_value_info("x", TensorProto.UINT8, [1, 2, 400, 400])],
        [helper.make_tensor_value_info("y", TensorProto.UINT8, None)],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    assert neighbour_swap_as_concat(model) == []


def test_unnamed_swaps_get_names_of_their_own() -> None:
    """Two unnamed Transposes in a row: every value and node name the rewrite makes is new."""
    nodes = [
        helper.make_node("Transpose", ["x"], ["t"], perm=[0, 2, 1, 3]),
        helper.make_node("Transpose", ["t"], ["y"], perm=[0, 2, 1, 3]),
    ]
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("x", TensorProto.UINT8, ["n", 2, 2, 40000])],
        [helper.make_tensor_value_info("y", TensorProto.UINT8, None)],
    )
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])
    x = {"x": RNG.integers(0, 256, (3, 2, 2, 40000), dtype=np.uint8)}
    before = _run(model, x)
    assert neighbour_swap_as_concat(model) == ["t", "y"]
    outputs = [o for n in model.graph.node for o in n.output]
    named = [n.name for n in model.graph.node if n.name]
    assert len(outputs) == len(set(outputs)) and len(named) == len(set(named))
    np.testing.assert_array_equal(_run(model, x), before)


def _with_output(model: onnx.ModelProto, name: str) -> onnx.ModelProto:
    model.graph.output.append(helper.make_tensor_value_info(name, TensorProto.FLOAT, None))
    return model


def test_graph_outputs_are_never_dropped_or_retyped() -> None:
    """A value the model's caller reads counts as a second reader for every rewrite."""
    stem = _with_output(_stem(7, 3), "t")
    assert stem_as_space_to_depth(stem) == ["stem"]
    assert "t" in [o for n in stem.graph.node for o in n.output]  # the channels-first input is still made
    up = _with_output(_upsample(2, 2, relu=True), "u")
    assert upsample_as_depth_to_space(up) == ["up"]
    assert _ops(up) == ["Conv", "DepthToSpace", "Relu"]  # the ReLU stays after: "u" is read before it
    nodes = [
        helper.make_node("Relu", ["x"], ["r"]),
        helper.make_node("Transpose", ["r"], ["a"], perm=[0, 2, 1]),
        helper.make_node("QuantizeLinear", ["a", "s", "z"], ["q"]),
        helper.make_node("DequantizeLinear", ["q", "s", "z"], ["y"]),
    ]
    chain = _with_output(
        _model(nodes, [helper.make_tensor_value_info("x", TensorProto.FLOAT, [1, 4, 6])], _scalars()), "a"
    )
    assert data_movement_on_quantized_values(chain) == []
    x = {"x": RNG.normal(size=(1, 4, 6)).astype(np.float32)}
    up_x = {"x": RNG.normal(size=(1, 6, 7, 9)).astype(np.float32)}
    for model, feeds in ((stem, {"x": RNG.normal(size=(2, 20, 16, 3)).astype(np.float32)}), (up, up_x), (chain, x)):
        _run(model, feeds)
