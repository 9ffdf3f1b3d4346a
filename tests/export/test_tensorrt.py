"""The static TensorRT check: its verdicts on hand-made graphs, and what it says of the real exports."""

from __future__ import annotations

import json

import numpy as np
import onnx
import pytest
from onnx import TensorProto, helper, numpy_helper

from fisheye_infer.export.tensorrt_check import MAX_TOPK_K, check_tensorrt
from fisheye_infer.runtime.artifact import TensorRTReport, parse_meta, read_meta

F, I64 = TensorProto.FLOAT, TensorProto.INT64


def _model(
    nodes: list[onnx.NodeProto],
    inputs: list[onnx.ValueInfoProto],
    outputs: list[onnx.ValueInfoProto],
    initializers: list[onnx.TensorProto] = (),
    opset: int = 18,
) -> onnx.ModelProto:
    graph = helper.make_graph(nodes, "g", inputs, outputs, list(initializers))
    return helper.make_model(graph, opset_imports=[helper.make_opsetid("", opset)], ir_version=10)


def _scores(shape: list[int | str] = ("batch", 10000)) -> onnx.ValueInfoProto:
    return helper.make_tensor_value_info("x", F, list(shape))


def _topk(k: int) -> onnx.ModelProto:
    node = helper.make_node("TopK", ["x", "k"], ["values", "indices"], name="rank", axis=1)
    outs = [helper.make_tensor_value_info("values", F, None), helper.make_tensor_value_info("indices", I64, None)]
    return _model([node], [_scores()], outs, [numpy_helper.from_array(np.array([k], np.int64), "k")])


def _errors(report: TensorRTReport) -> list:
    return [f for f in report.findings if f.severity == "error"]


def test_clean_graph_is_compatible() -> None:
    weight = numpy_helper.from_array(np.ones((8, 3, 3, 3), np.float32), "w")
    nodes = [
        helper.make_node("Conv", ["x", "w"], ["c"], name="conv", pads=[1, 1, 1, 1]),
        helper.make_node("Relu", ["c"], ["y"], name="relu"),
    ]
    model = _model(
        nodes,
        [helper.make_tensor_value_info("x", F, ["batch", 3, 32, 32])],
        [helper.make_tensor_value_info("y", F, None)],
        [weight],
    )
    report = check_tensorrt(model)
    assert report.compatible and report.findings == ()
    assert report.summary().endswith("compatible (0 note(s))")


def test_unsupported_op_is_refused_by_name() -> None:
    node = helper.make_node("Det", ["x"], ["y"], name="the_det")
    report = check_tensorrt(
        _model(
            [node], [helper.make_tensor_value_info("x", F, [1, 3, 3])], [helper.make_tensor_value_info("y", F, None)]
        )
    )
    assert not report.compatible
    (error,) = _errors(report)
    assert (error.node, error.op_type) == ("the_det", "Det") and "not supported" in error.message
    assert "the_det (Det)" in report.summary()


def test_custom_domain_op_needs_a_plugin() -> None:
    node = helper.make_node("Inverse", ["x"], ["y"], name="inv", domain="com.microsoft")
    model = _model(
        [node], [helper.make_tensor_value_info("x", F, [1, 3, 3])], [helper.make_tensor_value_info("y", F, None)]
    )
    model.opset_import.append(helper.make_opsetid("com.microsoft", 1))
    (error,) = _errors(check_tensorrt(model))
    assert error.node == "inv" and "plugin" in error.message


def test_topk_beyond_3840_is_refused() -> None:
    report = check_tensorrt(_topk(5000))
    assert not report.compatible
    (error,) = _errors(report)
    assert (
        error.node == "rank"
        and error.op_type == "TopK"
        and "K=5000" in error.message
        and str(MAX_TOPK_K) in error.message
    )


@pytest.mark.parametrize("k", [100, MAX_TOPK_K])
def test_topk_within_3840_is_fine(k: int) -> None:
    assert check_tensorrt(_topk(k)).compatible


def test_topk_with_a_run_time_k_is_a_note() -> None:
    nodes = [
        helper.make_node("Shape", ["x"], ["s"], name="shape", start=1),
        helper.make_node("TopK", ["x", "s"], ["values", "indices"], name="rank", axis=1),
    ]
    outs = [helper.make_tensor_value_info("values", F, None), helper.make_tensor_value_info("indices", I64, None)]
    report = check_tensorrt(_model(nodes, [_scores()], outs))
    assert report.compatible and any(f.node == "rank" and "run time" in f.message for f in report.findings)


def _grid_sample(input_rank: int, opset: int = 18, **attrs: object) -> onnx.ModelProto:
    spatial = [8] * (input_rank - 2)
    node = helper.make_node("GridSample", ["x", "grid"], ["y"], name="warp", **attrs)
    inputs = [
        helper.make_tensor_value_info("x", F, ["batch", 16, *spatial]),
        helper.make_tensor_value_info("grid", F, ["batch", *spatial, input_rank - 2]),
    ]
    return _model([node], inputs, [helper.make_tensor_value_info("y", F, None)], opset=opset)


def test_grid_sample_4d_bilinear_zeros_is_fine() -> None:
    assert check_tensorrt(_grid_sample(4, mode="bilinear", padding_mode="zeros", align_corners=1)).compatible


def test_grid_sample_5d_is_refused() -> None:
    report = check_tensorrt(_grid_sample(5, opset=20, mode="linear"))
    assert not report.compatible
    assert any(f.node == "warp" and "4-D" in f.message for f in _errors(report))


def test_grid_sample_opset_20_mode_names_are_refused() -> None:
    """TensorRT 10.1's importer knows bilinear/nearest/bicubic and turns anything else into nearest, silently."""
    (error,) = _errors(check_tensorrt(_grid_sample(4, opset=20, mode="linear")))
    assert error.node == "warp" and "'linear'" in error.message and "nearest" in error.message


def test_scatter_nd_with_reduction_is_refused() -> None:
    node = helper.make_node("ScatterND", ["x", "idx", "upd"], ["y"], name="pool", reduction="add")
    inputs = [
        helper.make_tensor_value_info("x", F, [10, 4]),
        helper.make_tensor_value_info("idx", I64, [6, 1]),
        helper.make_tensor_value_info("upd", F, [6, 4]),
    ]
    (error,) = _errors(check_tensorrt(_model([node], inputs, [helper.make_tensor_value_info("y", F, None)])))
    assert error.node == "pool" and "reduction" in error.message


def test_dynamic_spatial_input_dimension_is_a_finding() -> None:
    node = helper.make_node("Relu", ["x"], ["y"], name="relu")
    model = _model(
        [node],
        [helper.make_tensor_value_info("x", F, ["batch", 3, "height", 32])],
        [helper.make_tensor_value_info("y", F, None)],
    )
    report = check_tensorrt(model)
    (finding,) = report.findings
    assert (
        finding.severity == "note"
        and "'x'" in finding.message
        and "[2]" in finding.message
        and "optimization profile" in finding.message
    )
    assert report.compatible  # TensorRT builds it for a profile; it is worth knowing, not refused


def test_input_without_rank_is_refused() -> None:
    node = helper.make_node("Relu", ["x"], ["y"], name="relu")
    report = check_tensorrt(
        _model([node], [helper.make_tensor_value_info("x", F, None)], [helper.make_tensor_value_info("y", F, None)])
    )
    assert not report.compatible and "no known rank" in _errors(report)[0].message


def test_axes_computed_at_run_time_are_refused() -> None:
    nodes = [
        helper.make_node("Shape", ["x"], ["s"], name="shape", start=0, end=1),
        helper.make_node("Sub", ["s", "one"], ["axes"], name="minus_one"),
        helper.make_node("Unsqueeze", ["x", "axes"], ["y"], name="unsqueeze"),
    ]
    model = _model(
        nodes,
        [helper.make_tensor_value_info("x", F, [1, 4])],
        [helper.make_tensor_value_info("y", F, None)],
        [numpy_helper.from_array(np.array([1], np.int64), "one")],
    )
    (error,) = _errors(check_tensorrt(model))
    assert error.node == "unsqueeze" and "initializer" in error.message


def test_uint8_inside_the_network_is_refused_but_at_its_input_is_fine() -> None:
    cast = helper.make_node("Cast", ["img"], ["f"], name="to_float", to=F)
    ok = _model(
        [cast],
        [helper.make_tensor_value_info("img", TensorProto.UINT8, ["batch", 8, 8, 3])],
        [helper.make_tensor_value_info("f", F, None)],
    )
    assert check_tensorrt(ok).compatible
    transpose = helper.make_node("Transpose", ["img"], ["t"], name="hwc_to_chw", perm=[0, 3, 1, 2])
    bad = _model(
        [transpose, helper.make_node("Cast", ["t"], ["f"], name="to_float", to=F)],
        [helper.make_tensor_value_info("img", TensorProto.UINT8, ["batch", 8, 8, 3])],
        [helper.make_tensor_value_info("f", F, None)],
    )
    errors = _errors(check_tensorrt(bad))
    assert errors and all(e.node == "hwc_to_chw" for e in errors) and "UINT8" in errors[0].message


def test_int64_index_tables_are_a_note() -> None:
    node = helper.make_node("Gather", ["x", "table"], ["y"], name="pool", axis=0)
    table = numpy_helper.from_array(np.array([0, 3, 3_000_000_000], np.int64), "table")
    report = check_tensorrt(
        _model(
            [node],
            [helper.make_tensor_value_info("x", F, [4, 2])],
            [helper.make_tensor_value_info("y", F, None)],
            [table],
        )
    )
    assert report.compatible
    (note,) = [f for f in report.findings if "initializer" in f.message]
    assert note.severity == "note" and "table (3,)" in note.message and "do NOT fit in INT32" in note.message


def test_shape_constants_are_not_reported_as_int64_data() -> None:
    node = helper.make_node("Reshape", ["x", "shape"], ["y"], name="flatten")
    model = _model(
        [node],
        [helper.make_tensor_value_info("x", F, [4, 2])],
        [helper.make_tensor_value_info("y", F, None)],
        [numpy_helper.from_array(np.array([8], np.int64), "shape")],
    )
    assert check_tensorrt(model).findings == ()


# -- the kit's real exports ---------------------------------------------------------------------


def test_metadata_without_the_report_still_parses(bevdet_export) -> None:
    """Files written before the check have no ``tensorrt`` field; the field is optional."""
    meta = read_meta(bevdet_export.onnx).model_dump(mode="json")
    meta.pop("tensorrt")
    assert parse_meta(json.dumps(meta)).tensorrt is None


def test_bevdet_export_passes_the_tensorrt_parser_check(bevdet_export) -> None:
    """FisheyeBEVDet: compatible; two notes: the pooling plan's INT64 index tables (all values fit
    in INT32) and the INT64 index values computed from them and from the top-k."""
    report = read_meta(bevdet_export.onnx).tensorrt
    assert report is not None and report == check_tensorrt(onnx.load(str(bevdet_export.onnx)))
    assert report.compatible and {f.severity for f in report.findings} == {"note"}
    tables = next(f for f in report.findings if "initializer" in f.message)
    assert "geom.pool." in tables.message and "every value fits in INT32" in tables.message
    assert report.summary() in bevdet_export.result.summary()


def test_petr_export_passes_the_tensorrt_parser_check(petr_export) -> None:
    """FisheyePETR: compatible; notes on INT64 data values (the top-k's indices and labels) only."""
    report = read_meta(petr_export.onnx).tensorrt
    assert report is not None and report.compatible and {f.severity for f in report.findings} == {"note"}
    assert all("INT64" in f.message for f in report.findings)
    assert "compatible" in petr_export.result.summary()


def test_int8_file_is_for_onnx_runtime_not_tensorrt(small_export, tmp_path) -> None:
    """ONNX Runtime's static QDQ (UINT8 activations with zero points, INT32 biases, data movement on
    UINT8 values) is refused by TensorRT, which quantizes to INT8 symmetrically; the int8 file's
    metadata says so."""
    from fisheye_infer.export.exporter import export_int8
    from fisheye_infer.export.options import Comparison, Int8Options

    result = export_int8(
        small_export.onnx,
        tmp_path / "small.int8.onnx",
        options=Int8Options(calib_frames=1, scope="network"),
        comparison=Comparison(frames=1),
        force=True,
        progress=lambda _: None,
    )
    report = read_meta(result.path).tensorrt
    assert report is not None and not report.compatible
    errors = _errors(report)
    assert {"QuantizeLinear", "DequantizeLinear"} <= {e.op_type for e in errors}
    assert {e.op_type for e in errors} <= {
        "QuantizeLinear",
        "DequantizeLinear",
        "Reshape",
        "Transpose",
        "DepthToSpace",
        "Split",
        "Concat",
    }
    assert any("zero point" in e.message for e in errors) and any("INT32" in e.message for e in errors)
    assert all(
        "UINT8" in e.message for e in errors if e.op_type in ("Reshape", "Transpose", "DepthToSpace", "Split", "Concat")
    )
    assert "int8 file: TensorRT ONNX parser" in result.summary() and "NOT compatible" in result.summary()
