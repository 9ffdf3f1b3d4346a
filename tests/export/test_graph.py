"""Graph rewrites of the exporter: folding the normalisation's division into the first convolution."""

from __future__ import annotations

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

from fisheye_infer.export.graph import fold_input_scale

STD = np.array([58.395, 57.12, 57.375], np.float32)
MEAN = np.array([123.675, 116.28, 103.53], np.float32)


def _model(
    *,
    five_d: bool = False,
    second_reader: bool = False,
    group: int = 1,
    scale: np.ndarray = STD,
    reshape_to: tuple[int, ...] = (2, 3, 8, 8),
    scaled_out: bool = False,
) -> onnx.ModelProto:
    """images -> Sub(mean) -> Div(std) [-> Reshape] -> Conv(3x3, pad 1) -> y; five_d: (1, 2, 3, 8, 8) images."""
    lead = (1, 2) if five_d else (2,)
    shape_c = (*[1] * len(lead), 3, 1, 1)
    w = np.random.default_rng(0).normal(size=(4, 3 // group, 3, 3)).astype(np.float32)
    inits = [
        numpy_helper.from_array(MEAN.reshape(shape_c), "mean"),
        numpy_helper.from_array(scale.astype(np.float32).reshape((*[1] * len(lead), scale.size, 1, 1)), "std"),
        numpy_helper.from_array(w, "w"),
        numpy_helper.from_array(np.arange(4, dtype=np.float32), "b"),
        numpy_helper.from_array(np.array(reshape_to, np.int64), "shape"),
    ]
    nodes = [
        helper.make_node("Sub", ["x", "mean"], ["centred"]),
        helper.make_node("Div", ["centred", "std"], ["scaled"]),
    ]
    conv_in = "scaled"
    if five_d:
        nodes.append(helper.make_node("Reshape", ["scaled", "shape"], ["flat"]))
        conv_in = "flat"
    nodes.append(helper.make_node("Conv", [conv_in, "w", "b"], ["y"], name="conv1", pads=[1, 1, 1, 1], group=group))
    outputs = [helper.make_tensor_value_info("y", TensorProto.FLOAT, None)]
    if second_reader:
        nodes.append(helper.make_node("Relu", ["scaled"], ["also"]))
        outputs.append(helper.make_tensor_value_info("also", TensorProto.FLOAT, None))
    if scaled_out:  # the caller reads the normalised images too
        outputs.append(helper.make_tensor_value_info("scaled", TensorProto.FLOAT, None))
    x = helper.make_tensor_value_info("x", TensorProto.FLOAT, [*lead, 3, 8, 8])
    graph = helper.make_graph(nodes, "g", [x], outputs, initializer=inits)
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", 18)])


def _run(model: onnx.ModelProto, x: np.ndarray) -> np.ndarray:
    session = ort.InferenceSession(model.SerializeToString(), providers=["CPUExecutionProvider"])
    return session.run(["y"], {"x": x})[0]


@pytest.mark.parametrize("five_d", [False, True])
def test_division_folds_into_the_first_convolution(five_d: bool) -> None:
    model = _model(five_d=five_d)
    x = np.random.default_rng(1).uniform(0, 255, (1, 2, 3, 8, 8) if five_d else (2, 3, 8, 8)).astype(np.float32)
    before = _run(model, x)
    assert fold_input_scale(model) == ["conv1"]
    assert [n.op_type for n in model.graph.node] == ["Sub", *(["Reshape"] if five_d else []), "Conv"]
    assert "std" not in {i.name for i in model.graph.initializer}
    np.testing.assert_allclose(_run(model, x), before, rtol=1e-5, atol=1e-4)  # the border too: padding stays 0


@pytest.mark.parametrize(
    "case", ["second reader", "graph output", "grouped", "not per channel", "negative", "reshape moves channels"]
)
def test_division_stays_where_folding_would_change_the_result(case: str) -> None:
    model = {
        "second reader": lambda: _model(second_reader=True),
        "graph output": lambda: _model(scaled_out=True),
        "grouped": lambda: _model(group=3),
        "not per channel": lambda: _model(scale=np.array([2.0], np.float32)),
        "negative": lambda: _model(scale=np.array([1.0, -1.0, 2.0], np.float32)),
        "reshape moves channels": lambda: _model(five_d=True, reshape_to=(2, 3, 4, 16)),
    }[case]()
    nodes = [n.op_type for n in model.graph.node]
    assert fold_input_scale(model) == []
    assert [n.op_type for n in model.graph.node] == nodes
