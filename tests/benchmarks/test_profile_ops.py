"""``benchmarks/profile_ops.py``: ONNX Runtime's profile of a real file, grouped by operator and input shapes."""

from __future__ import annotations

import json
import sys
import tempfile
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
from onnx import TensorProto, helper, numpy_helper

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))

import profile_ops  # noqa: E402


def _kernels(tmp: Path) -> list[dict]:
    """One run's kernel events of a graph of three MatMuls, two of them on the same shapes."""
    weights = [numpy_helper.from_array(np.eye(n, dtype=np.float32), f"w{n}") for n in (8, 16)]
    nodes = [
        helper.make_node("MatMul", ["x", "w8"], ["a"]),
        helper.make_node("MatMul", ["a", "w8"], ["b"]),
        helper.make_node("Concat", ["b", "b"], ["c"], axis=1),
        helper.make_node("MatMul", ["c", "w16"], ["y"]),
    ]
    graph = helper.make_graph(
        nodes,
        "g",
        [helper.make_tensor_value_info("x", TensorProto.FLOAT, [64, 8])],
        [helper.make_tensor_value_info("y", TensorProto.FLOAT, [64, 16])],
        weights,
    )
    path = tmp / "g.onnx"
    onnx.save(helper.make_model(graph, opset_imports=[helper.make_opsetid("", 17)]), path)
    options = ort.SessionOptions()
    options.enable_profiling = True
    options.profile_file_prefix = str(tmp / "ort")
    options.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    session = ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])
    session.run(None, {"x": np.ones((64, 8), np.float32)})
    events = json.loads(Path(session.end_profiling()).read_text())
    return [e for e in events if e.get("cat") == "Node" and e["name"].endswith("_kernel_time")]


def test_nodes_of_the_same_operator_and_shapes_are_one_row() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        kernels = _kernels(Path(tmp))
    rows = profile_ops._by_shapes(kernels, top=10)
    matmuls = {r["input shapes"]: r for r in rows if r["operator"] == "MatMul"}  # weights ONNX Runtime packed
    assert matmuls.keys() == {"float[64, 8]", "float[64, 16]"}  # at load time are not among a kernel's inputs
    assert matmuls["float[64, 8]"]["nodes"] == 2 and matmuls["float[64, 16]"]["nodes"] == 1
    assert {r["input shapes"] for r in rows if r["operator"] == "Concat"} == {"float[64, 8] x float[64, 8]"}
    assert sum(r["nodes"] for r in rows) == len(kernels) == 4
    assert abs(sum(r["share"] for r in rows) - 1.0) < 1e-9
    assert [r["ms"] for r in rows] == sorted((r["ms"] for r in rows), reverse=True)
    assert len(profile_ops._by_shapes(kernels, top=1)) == 1
