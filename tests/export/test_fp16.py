"""The fp16 file: what stays float32 and why, and its evidence against the fp32 file."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import pytest
from onnx import TensorProto, helper, numpy_helper

pytest.importorskip("torch")

from fisheye_infer.commands import export as export_command
from fisheye_infer.errors import ExportError
from fisheye_infer.export.exporter import (
    Fp16Result,
    export,
    export_fp16,
    export_int8,
    fp16_path_for,
    verification_frames,
)
from fisheye_infer.export.fp16 import to_float16
from fisheye_infer.export.fp16_parity import evaluated_with, fp16_parity
from fisheye_infer.export.options import Comparison, Int8Options
from fisheye_infer.runtime.artifact import read_meta

F, H, I64 = TensorProto.FLOAT, TensorProto.FLOAT16, TensorProto.INT64


def _toy() -> onnx.ModelProto:
    """uint8 in; a weight, a geometry table, a float index computation (index // 3 through float) and a default ConstantOfShape."""
    nodes = [
        helper.make_node("Cast", ["img"], ["x"], name="to_float", to=F),
        helper.make_node("Mul", ["x", "w"], ["a"], name="scale"),
        helper.make_node("Add", ["a", "geom.offset"], ["b"], name="shift"),
        helper.make_node("Shape", ["b"], ["s"], name="shape"),
        helper.make_node("ConstantOfShape", ["s"], ["zeros"], name="zeros"),
        helper.make_node("Add", ["b", "zeros"], ["c"], name="plus_zero"),
        helper.make_node("ReduceMax", ["c", "axis1"], ["scores"], name="score", keepdims=0),
        helper.make_node("Cast", ["index"], ["index_f"], name="index_to_float", to=F),
        helper.make_node("Div", ["index_f", "three"], ["q"], name="div"),
        helper.make_node("Floor", ["q"], ["qf"], name="floor"),
        helper.make_node("Cast", ["qf"], ["label"], name="to_int", to=I64),
    ]
    inputs = [
        helper.make_tensor_value_info("img", TensorProto.UINT8, ["batch", 4]),
        helper.make_tensor_value_info("index", I64, ["batch"]),
    ]
    outputs = [
        helper.make_tensor_value_info("scores", F, ["batch"]),
        helper.make_tensor_value_info("label", I64, ["batch"]),
    ]
    inits = [
        numpy_helper.from_array(np.full(4, 0.5, np.float32), "w"),
        numpy_helper.from_array(np.array([0.1, 0.2, 0.3, 0.4], np.float32), "geom.offset"),
        numpy_helper.from_array(np.array(3.0, np.float32), "three"),
        numpy_helper.from_array(np.array([1], np.int64), "axis1"),
    ]
    return helper.make_model(
        helper.make_graph(nodes, "toy", inputs, outputs, inits),
        opset_imports=[helper.make_opsetid("", 18)],
        ir_version=10,
    )


def test_to_float16_keeps_interface_geometry_and_index_arithmetic_float32() -> None:
    half, plan = to_float16(_toy())
    inits = {i.name: i.data_type for i in half.graph.initializer}
    assert inits == {
        "w": H,
        "geom.offset": F,
        "three": F,
        "axis1": I64,
    }  # the weight halves; the geometry table and the index divisor do not
    assert [(v.name, v.type.tensor_type.elem_type) for v in half.graph.input] == [
        ("img", TensorProto.UINT8),
        ("index", I64),
    ]
    assert [(v.name, v.type.tensor_type.elem_type) for v in half.graph.output] == [("scores", F), ("label", I64)]
    assert plan.index_nodes == 4 and plan.geometry_tables == 1
    img = np.array([[0, 1, 2, 255]], np.uint8)
    index = np.array([2047 * 3 + 2], np.int64)  # beyond float16's exact integers once multiplied; exact in float32
    scores, label = ort.InferenceSession(half.SerializeToString(), providers=["CPUExecutionProvider"]).run(
        None, {"img": img, "index": index}
    )
    assert scores.dtype == np.float32 and abs(float(scores[0]) - 127.9) < 0.1
    assert label.tolist() == [2047]


def test_to_float16_never_modifies_its_input() -> None:
    model = _toy()
    before = model.SerializeToString()
    to_float16(model)
    assert model.SerializeToString() == before


@pytest.fixture(scope="module")
def petr_fp16(petr_export, tmp_path_factory: pytest.TempPathFactory) -> Fp16Result:
    """The kit's FisheyePETR export (the session's file, not exported again) in float16, judged on one frame."""
    out = fp16_path_for(tmp_path_factory.mktemp("fp16") / petr_export.onnx.name)
    return export_fp16(petr_export.onnx, out, comparison=Comparison(frames=1), progress=lambda _: None)


def test_fp16_file_metadata_and_parity(petr_export, petr_fp16: Fp16Result) -> None:
    assert petr_fp16.path is not None and petr_fp16.path.name == "fisheye-petr.fp16.onnx"
    meta, fp32 = read_meta(petr_fp16.path), read_meta(petr_export.onnx)
    assert meta.quantization is not None and meta.quantization.mode == "fp16" and "geom.*" in meta.quantization.scope
    assert meta.model_id == fp32.model_id + "-fp16" and fp32.quantization is None
    p = meta.parity
    assert p is not None and p.reference == "fp32-onnx" and p.evaluated_with == "onnxruntime-cpu" and p.frames == 1
    assert p.passed and p.top_matched_fraction >= 0.95 and p.labels_equal
    assert p.max_box_abs_diff_m < 1.0 and p.max_score_abs_diff < 0.05 and p.max_rank_score_abs_diff < 0.05
    assert p.replayed is not None and p.replayed.top_matched_fraction >= 0.95 and p.replayed.max_box_abs_diff_m < 0.5
    assert meta.tensorrt is not None and meta.tensorrt.compatible
    assert "top-50 boxes matched" in petr_fp16.summary() and "fp16 file: TensorRT ONNX parser" in petr_fp16.summary()


def test_fp16_file_is_float16_inside_with_the_fp32_interface_and_tables(petr_export, petr_fp16: Fp16Result) -> None:
    half, full = onnx.load(str(petr_fp16.path)), onnx.load(str(petr_export.onnx))
    io = lambda m: [(v.name, v.type.tensor_type.elem_type) for v in list(m.graph.input) + list(m.graph.output)]  # noqa: E731
    assert io(half) == io(full)
    tables = {i.name: i for i in full.graph.initializer if i.name.startswith("geom.")}
    for init in half.graph.initializer:
        if init.name in tables:
            assert init.data_type == tables[init.name].data_type and init.raw_data == tables[init.name].raw_data, (
                init.name
            )
    weights = [i for i in half.graph.initializer if not i.name.startswith("geom.") and i.data_type in (F, H)]
    assert sum(i.data_type == H for i in weights) > 0.9 * len(weights)
    assert petr_fp16.path.stat().st_size < 0.7 * petr_export.onnx.stat().st_size


def test_reduced_precision_files_are_not_converted_again(petr_fp16: Fp16Result, tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="already a reduced-precision file"):
        export_fp16(petr_fp16.path, tmp_path / "again.onnx", progress=lambda _: None)
    with pytest.raises(ExportError, match="already quantized"):
        export_int8(
            petr_fp16.path, tmp_path / "again.int8.onnx", options=Int8Options(calib_frames=1), progress=lambda _: None
        )


@pytest.mark.slow  # a whole export: make test-fast leaves it out
def test_export_with_fp16_writes_both_files(small_export, small_bevdet_config, tmp_path: Path) -> None:
    """``export(fp16=True)`` (``--fp16``): the verified fp32 file at ``out``, the fp16 file next to it, both in the summary."""
    out = tmp_path / "m.onnx"
    result = export(
        small_export.ckpt,
        out,
        config=small_bevdet_config,
        rig=read_meta(small_export.onnx).rig,
        frames=1,
        threads=(1,),
        fp16=True,
        force=True,
        progress=lambda _: None,
    )
    assert read_meta(out).quantization is None and read_meta(out).tensorrt is not None
    assert result.fp16 is not None and result.fp16.path == tmp_path / "m.fp16.onnx"
    assert read_meta(result.fp16.path).quantization.mode == "fp16"
    summary = result.summary()
    assert (
        "parity vs PyTorch" in summary
        and "fp16 vs the fp32 ONNX file" in summary
        and summary.count("TensorRT ONNX parser") == 2
    )


def test_cli_takes_fp16() -> None:
    parser = argparse.ArgumentParser()
    export_command.configure(parser)
    assert parser.parse_args(["--ckpt", "c.pth", "--out", "m.onnx", "--fp16"]).fp16


def test_parity_runs_the_candidate_where_it_is_asked_to(small_export) -> None:
    """``candidate_providers``: the file under test runs in those providers (a GPU's, in benchmarks/gpu.py), the fp32
    reference on the CPU; the report names where. The fp32 file against itself is exact; a provider this onnxruntime
    lacks is refused by name."""
    frames = verification_frames(read_meta(small_export.onnx).rig, 1)
    same = fp16_parity(
        small_export.onnx, small_export.onnx, frames, threads=1, candidate_providers=[("CPUExecutionProvider", {})]
    )
    assert (
        same.evaluated_with == "onnxruntime-cpu"
        and same.top_matched_fraction == 1.0
        and same.max_box_abs_diff_m == 0.0
        and same.passed
    )
    assert evaluated_with(["CUDAExecutionProvider", "CPUExecutionProvider"]) == "onnxruntime-cuda"
    with pytest.raises(
        ExportError, match=r"fp16: ONNX Runtime \(onnxruntime-nosuch\) cannot run .*NoSuchExecutionProvider"
    ):
        fp16_parity(
            small_export.onnx, small_export.onnx, frames, threads=1, candidate_providers=["NoSuchExecutionProvider"]
        )
