"""int8 export: static QDQ of every weighted layer (or of the image trunk alone), with evidence against the fp32 file."""

from __future__ import annotations

from collections import Counter
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

pytest.importorskip("torch")

from fisheye_infer.cli import main
from fisheye_infer.errors import ExportError, ParityError
from fisheye_infer.eval.top_match import match_top, top_matched
from fisheye_infer.export import reduced as reduced_module
from fisheye_infer.export.exporter import Int8Result, export, export_int8
from fisheye_infer.export.graph import save_model, set_metadata
from fisheye_infer.export.graph_stages import name_nodes
from fisheye_infer.export.int8_rewrites import before_quantization
from fisheye_infer.export.int8_scope import WEIGHTED_OPS, image_region, int8_nodes, module_of, quantized_scope
from fisheye_infer.export.options import Comparison, Int8Options
from fisheye_infer.export.quantize import (
    QUANT_OPS,
    FrameReader,
    architecture_float,
    check_weight_range,
    eight_bit_constants,
    int8_path_for,
    quantize,
)
from fisheye_infer.precision import WEIGHT_QMAX
from fisheye_infer.runtime.artifact import Quantization, read_meta
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.tools.cpu import CpuInfo, int8_saturation_warning


@pytest.fixture(scope="module")
def small_int8(small_export, tmp_path_factory: pytest.TempPathFactory) -> Int8Result:
    """The reduced FisheyeBEVDet quantized on two calibration frames (kept whatever its box match)."""
    out = tmp_path_factory.mktemp("int8") / "small.int8.onnx"
    return export_int8(
        small_export.onnx,
        out,
        options=Int8Options(calib_frames=2, scope="network"),
        comparison=Comparison(frames=2),
        force=True,
        progress=lambda _: None,
    )


def _geometry(path: Path) -> dict[str, np.ndarray]:
    return {
        i.name: numpy_helper.to_array(i) for i in onnx.load(str(path)).graph.initializer if i.name.startswith("geom.")
    }


def _region_names(path: Path) -> tuple[onnx.ModelProto, set[str]]:
    model = onnx.load(str(path))
    return model, set(image_region(model))


def _int8_layers(model: onnx.ModelProto) -> set[str]:
    """Names of the layers that run in int8: those whose weight comes out of a DequantizeLinear of an initializer."""
    inits = {i.name for i in model.graph.initializer}
    weight_dq = {n.output[0] for n in model.graph.node if n.op_type == "DequantizeLinear" and n.input[0] in inits}
    return {
        n.name for n in model.graph.node if n.op_type in WEIGHTED_OPS and len(n.input) > 1 and n.input[1] in weight_dq
    }


def _ops(model: onnx.ModelProto) -> list[str]:
    return [n.op_type for n in model.graph.node]


def _named(path: Path) -> onnx.ModelProto:
    model = onnx.load(str(path))
    name_nodes(model)
    return model


def test_network_scope_quantizes_the_weighted_layers_and_nothing_else(small_export, small_int8: Int8Result) -> None:
    fp32, model = _named(small_export.onnx), onnx.load(str(small_int8.path))
    keep_float = architecture_float(small_export.onnx)
    assert (
        len(before_quantization(fp32, int8_nodes(fp32, "network", keep_float))) == 2
    )  # the stem and the upsampling, as quantize does
    assert keep_float == (
        "bbox_head.heatmap_head.1",
        "bbox_head.prediction_heads",
        "bbox_head.decoder",
        "bbox_head.class_encoding",
    )
    chosen = set(int8_nodes(fp32, "network", keep_float))
    weighted = {n.name for n in fp32.graph.node if n.name in chosen and n.op_type in WEIGHTED_OPS}
    assert _int8_layers(model) == weighted
    params = {i.name for i in fp32.graph.initializer}
    modules = {module_of(n, params) for n in fp32.graph.node if n.name in weighted}
    assert any(m.startswith("img_backbone.") for m in modules) and any(m.startswith("pts_backbone.") for m in modules)
    assert (
        "view_transform.depthnet" in modules and {"bbox_head.shared_conv", "bbox_head.heatmap_head.0.conv"} <= modules
    )
    assert not any(m.startswith(keep_float) for m in modules)  # the rest of the head stays float
    assert {n.domain for n in model.graph.node} <= {"", "ai.onnx"}  # standard QDQ, no contrib ops
    geometry = {i.name for i in fp32.graph.initializer if i.name.startswith("geom.")}
    reads_tables = lambda m: sorted(
        (n.op_type, tuple(n.input), tuple(n.output)) for n in m.graph.node if geometry.intersection(n.input)
    )  # noqa: E731
    assert reads_tables(model) == reads_tables(fp32)  # warp, lift and pooling: the same float nodes on the same values
    ops = lambda m: Counter(n.op_type for n in m.graph.node if n.op_type not in QUANT_OPS)  # noqa: E731
    # only QuantizeLinear/DequantizeLinear pairs were added, and the stem's uint8 blocks are gathered by Split + Concat
    assert ops(model) - ops(fp32) == Counter({"Split": 1, "Concat": 1, "Reshape": 2})
    assert (ops(fp32) - ops(model))["Transpose"] == 1  # ... in place of one Transpose
    assert set(ops(fp32) - ops(model)) <= {
        "Relu",
        "Transpose",
    }  # a ReLU after a quantized layer is its U8 range (ORT drops it)


def test_int8_file_runs_the_stem_over_blocks_and_upsamples_without_convtranspose(
    small_export, small_int8: Int8Result
) -> None:
    """The stem convolution reads 12 channels (2 x 2 blocks of 3) through uint8 data movement, the blocks gathered by
    Split + Concat; the upsampling is an int8 1x1 convolution whose DepthToSpace reads uint8; the fp32 file keeps its own form."""
    fp32, model = onnx.load(str(small_export.onnx)), onnx.load(str(small_int8.path))
    assert "ConvTranspose" in _ops(fp32) and "ConvTranspose" not in _ops(model)
    inits = {i.name: i for i in model.graph.initializer}
    producers = {o: n for n in model.graph.node for o in n.output}
    weights = {
        n.output[0]: inits[n.input[0]]
        for n in model.graph.node
        if n.op_type == "DequantizeLinear" and n.input[0] in inits
    }
    convs = [n for n in model.graph.node if n.op_type == "Conv" and n.input[1] in weights]
    assert list(weights[convs[0].input[1]].dims[1:]) == [12, 4, 4]  # 7x7 stride 2 over 3 channels -> 4x4 over 12
    to_space = next(n for n in model.graph.node if n.op_type == "DepthToSpace")
    assert producers[to_space.input[0]].op_type == "QuantizeLinear"
    movement = [
        producers[convs[0].input[0]]
    ]  # DequantizeLinear <- Transpose <- Reshape <- Concat <- Reshape <- Split <- Reshape <- QuantizeLinear
    while movement[-1].op_type != "QuantizeLinear":
        movement.append(producers[movement[-1].input[0]])
    assert [n.op_type for n in movement][1:7] == ["Transpose", "Reshape", "Concat", "Reshape", "Split", "Reshape"]


def test_layers_kept_float_keep_their_form(small_export, tmp_path: Path) -> None:
    """The block forms are for int8 kernels; a stem or an upsampling left float keeps the form fp32 runs faster."""
    calibration = np.random.default_rng(0).integers(0, 255, (1, 4, 160, 160, 3), dtype=np.uint8)
    out = quantize(
        small_export.onnx,
        tmp_path / "float_ends.onnx",
        FrameReader(calibration),
        keep_float=("img_backbone.conv1", "pts_neck"),
    )
    model = onnx.load(str(out))
    assert "ConvTranspose" in _ops(model) and "DepthToSpace" not in _ops(model)
    stem = next(i for i in model.graph.initializer if i.name.endswith("img_backbone.conv1.weight"))
    assert list(stem.dims[1:]) == [3, 7, 7]


def test_trunk_scope_stays_in_the_backbone_and_neck(small_export, tmp_path: Path) -> None:
    calibration = np.random.default_rng(0).integers(0, 255, (1, 4, 160, 160, 3), dtype=np.uint8)
    out = quantize(small_export.onnx, tmp_path / "trunk.onnx", FrameReader(calibration), scope="trunk")
    model, region = _region_names(out)
    layers = _int8_layers(model)
    assert layers and layers <= region
    assert sum(n.op_type == "Conv" for n in model.graph.node if n.name in region) == len(layers)


@pytest.mark.parametrize("scope", ["network", "trunk"])
def test_keep_float_reaches_into_the_image_trunk(small_export, scope: str) -> None:
    model = _named(small_export.onnx)
    everything = set(int8_nodes(model, scope))
    layer1 = {
        n.name for n in model.graph.node if n.name in everything and module_of(n).startswith("img_backbone.layer1.")
    }
    assert any(n.op_type == "Conv" for n in model.graph.node if n.name in layer1)
    assert set(int8_nodes(model, scope, ("img_backbone.layer1",))) == everything - layer1
    with pytest.raises(ExportError, match="'img_backbone.layer': no node"):  # whole module names only
        int8_nodes(model, scope, ("img_backbone.layer",))
    conv1 = next(
        n.name for n in model.graph.node if n.op_type == "Conv" and n.input[1] == "model.img_backbone.conv1.weight"
    )
    assert conv1 in everything and conv1 not in int8_nodes(model, scope, ("img_backbone.conv1",))
    described = quantized_scope(model, scope, ("bbox_head", "img_backbone.layer1"), "asked for at export")
    float_part = described.split("float32: ", 1)[1]
    assert float_part.startswith(
        "bbox_head, img_backbone.layer1 (asked for at export)"
        if scope == "network"
        else "img_backbone.layer1 (asked for at export)"
    )


def test_keep_float_of_an_unknown_module_is_refused(small_export) -> None:
    with pytest.raises(ExportError, match="'img_backbone.conv9': no node of the graph belongs to that module"):
        int8_nodes(_named(small_export.onnx), "network", ("bbox_head", "img_backbone.conv9"))


def test_module_of_reads_the_recorded_module_path_or_the_weight_name(small_export) -> None:
    model = _named(small_export.onnx)
    depthnet = next(n for n in model.graph.node if n.op_type == "Conv" and n.input[1].endswith("depthnet.weight"))
    assert module_of(depthnet) == "view_transform.depthnet"
    del depthnet.metadata_props[:]
    assert module_of(depthnet) == "" and module_of(depthnet, {depthnet.input[1]}) == "view_transform.depthnet"
    # the first convolution, its BatchNorm folded in: recorded under the BatchNorm, owned by the convolution
    conv1 = next(n for n in model.graph.node if n.op_type == "Conv" and n.input[1] == "model.img_backbone.conv1.weight")
    assert module_of(conv1) == "img_backbone.bn1" and module_of(conv1, {conv1.input[1]}) == "img_backbone.conv1"


def test_an_unknown_scope_is_refused(small_export) -> None:
    with pytest.raises(ExportError, match="scope 'everything'"):
        int8_nodes(_named(small_export.onnx), "everything")


def test_geometry_initializers_unchanged_and_named(small_export, small_int8: Int8Result) -> None:
    meta = read_meta(small_export.onnx)
    before, after = _geometry(small_export.onnx), _geometry(small_int8.path)
    assert set(meta.geometry_initializers) <= set(after)
    for name in meta.geometry_initializers:
        assert after[name].dtype == before[name].dtype and np.array_equal(after[name], before[name]), name


def test_metadata_records_quantization_and_evidence(small_export, small_int8: Int8Result) -> None:
    meta = read_meta(small_int8.path)
    assert meta.quantization is not None and meta.quantization.mode == "int8-qdq"
    assert meta.quantization.calibration_frames == 2
    assert (
        meta.quantization.scope.startswith("network:")
        and "bbox_head.class_encoding (the architecture's int8_float)" in meta.quantization.scope
    )
    assert meta.parity is not None and meta.parity.reference == "fp32-onnx"
    assert 0.0 <= meta.parity.top_matched_fraction <= 1.0
    assert meta.model_id == read_meta(small_export.onnx).model_id + "-int8"
    assert read_meta(small_export.onnx).quantization is None  # the fp32 file is untouched
    assert "top-50 boxes matched" in small_int8.summary()


def test_detector_runs_the_int8_file(small_export, small_int8: Int8Result) -> None:
    detector = Detector(small_int8.path, threads=1)
    width, height = detector.info.image_size
    frame = np.random.default_rng(0).integers(0, 255, (len(detector.info.cameras), height, width, 3), dtype=np.uint8)
    dets = detector.detect(list(frame))
    assert detector.info.meta.quantization is not None
    assert dets.boxes.shape[1] == 7 and len(dets.boxes) == len(dets.scores)


def _boxes(
    centres: list[tuple[float, float]], labels: list[int], scores: list[float] | None = None
) -> list[np.ndarray]:
    k = len(centres)
    boxes = np.zeros((1, k, 7), np.float32)
    boxes[0, :, :2] = centres
    boxes[0, :, 3:6] = 1.0
    s = np.array([scores or np.linspace(0.9, 0.1, k)], np.float32)
    return [boxes, s, np.array([labels], np.int64), np.ones((1, k), bool)]


_TWO = _boxes([(0, 0), (10, 0)], [0, 1])


@pytest.mark.parametrize(
    ("reference", "candidate", "expected"),
    [
        pytest.param(_TWO, _boxes([(0, 0), (10, 0)], [0, 1]), 2, id="identical"),
        pytest.param(_TWO, _boxes([(0.3, 0.3), (10, 0.4)], [0, 1]), 2, id="within_half_a_metre"),
        pytest.param(_TWO, _boxes([(0.6, 0), (10, 0)], [0, 1]), 1, id="one_too_far"),
        pytest.param(_TWO, _boxes([(0, 0), (10, 0)], [1, 1]), 1, id="wrong_label"),
        pytest.param(
            _boxes([(0, 0), (0.05, 0)], [0, 0]), _boxes([(0.1, 0), (20, 0)], [0, 0]), 1, id="one_candidate_matches_once"
        ),
    ],
)
def test_top_matched_counts_same_label_within_radius(
    reference: list[np.ndarray], candidate: list[np.ndarray], expected: int
) -> None:
    kept = top_matched(reference, candidate)
    assert (kept.matched, kept.considered) == (expected, 2)


def test_top_matched_ignores_invalid_and_lower_ranked_boxes() -> None:
    reference = _boxes([(0, 0), (5, 0), (9, 0)], [0, 0, 0])
    reference[3][0, 1] = False  # not a valid reference box
    kept = top_matched(reference, _boxes([(0, 0), (5, 0), (30, 0)], [0, 0, 0]), top_k=1)
    assert (kept.matched, kept.considered) == (1, 1)


def _frames(*frames: list[np.ndarray]) -> list[np.ndarray]:
    return [np.concatenate(parts) for parts in zip(*frames, strict=True)]


def test_top_matched_standard_error_comes_from_the_spread_between_frames() -> None:
    """Both boxes kept in one frame, none in the other: share 1/2, and sqrt(2 / 1 * (1^2 + 1^2)) / 4 = 0.5;
    one box of two kept in each frame: the same share, with no spread between frames."""
    reference = _frames(_TWO, _TWO)
    hit, miss = _boxes([(0, 0), (10, 0)], [0, 1]), _boxes([(0, 0), (10, 0)], [2, 2])
    half = _boxes([(0, 0), (10, 0)], [0, 2])
    uneven, even = top_matched(reference, _frames(hit, miss)), top_matched(reference, _frames(half, half))
    assert (uneven.fraction, uneven.standard_error) == (0.5, pytest.approx(0.5))
    assert (even.fraction, even.standard_error) == (0.5, 0.0)
    assert top_matched(_TWO, miss).standard_error == 0.0  # one frame: not estimated
    assert [m.frame for m in match_top(reference, _frames(hit, miss))] == [0, 0, 1, 1]


def test_top_matched_counts_by_the_reference_score() -> None:
    reference = _boxes([(0, 0), (10, 0), (20, 0), (30, 0)], [0, 0, 0, 0], [0.5, 0.2, 0.1, 0.01])
    candidate = _boxes([(0, 0), (10, 5), (20, 0), (30, 5)], [0, 0, 0, 0])  # the 2nd and 4th moved 5 m
    assert top_matched(reference, candidate).by_score == {
        "score >= 0.3": (1, 1),
        "0.15-0.3": (0, 1),
        "0.05-0.15": (1, 1),
        "< 0.05": (0, 1),
    }


def test_match_top_reports_each_reference_box_in_rank_order_with_its_label() -> None:
    reference = _boxes([(0, 0), (10, 0), (20, 0)], [0, 1, 1], [0.5, 0.9, 0.7])
    candidate = _boxes([(0.1, 0), (10.2, 0), (21, 0)], [0, 1, 1], [0.4, 0.8, 0.7])
    found = match_top(reference, candidate)
    assert [(m.label, m.matched) for m in found] == [(1, True), (1, False), (0, True)]  # scores 0.9, 0.7, 0.5
    assert [m.score for m in found] == pytest.approx([0.9, 0.7, 0.5])  # the reference's, matched or not
    assert found[0].box_diff == pytest.approx(0.2) and found[0].score_diff == pytest.approx(0.1)
    kept = top_matched(reference, candidate)
    assert found[1].box_diff == 0.0 and (kept.matched, kept.considered) == (2, 3)


def test_frame_reader_feeds_one_frame_at_a_time_and_rewinds() -> None:
    frames = np.zeros((3, 4, 8, 8, 3), np.uint8)
    reader = FrameReader(frames)
    items = list(iter(reader.get_next, None))
    assert len(items) == 3 and items[0]["images"].shape == (1, 4, 8, 8, 3) and items[0]["camera_valid"].all()
    reader.rewind()
    assert reader.get_next() is not None
    reader.set_range(1, 2)  # how the calibrator takes the frames one at a time
    assert [item["images"].shape[0] for item in iter(reader.get_next, None)] == [1]
    reader.rewind()
    assert reader.get_next() is not None and reader.get_next() is None


def test_frame_reader_refuses_wrong_frames() -> None:
    with pytest.raises(ExportError, match="uint8"):
        FrameReader(np.zeros((1, 4, 8, 8, 3), np.float32))


def test_graph_without_warp_is_refused(tmp_path: Path) -> None:
    x = onnx.helper.make_tensor_value_info("images", onnx.TensorProto.FLOAT, [1, 3])
    y = onnx.helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [1, 3])
    graph = onnx.helper.make_graph([onnx.helper.make_node("Relu", ["images"], ["y"], name="relu")], "g", [x], [y])
    with pytest.raises(ExportError, match="no node samples the image features"):
        image_region(onnx.helper.make_model(graph))


def test_trunk_ends_at_the_gather_of_the_warp_taps() -> None:
    """images -> Relu -> Transpose -> Gather(geom.warp.index) -> MatMul(geom.warp.weight) -> Relu: the trunk is the first two."""
    h = onnx.helper
    x = h.make_tensor_value_info("images", onnx.TensorProto.FLOAT, [4, 3])
    valid = h.make_tensor_value_info("camera_valid", onnx.TensorProto.BOOL, [1])
    y = h.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [2, 1, 4])
    index = onnx.numpy_helper.from_array(np.array([0, 1, 2, 3, 1, 1, 0, 0], np.int64), "geom.warp.index")
    weight = onnx.numpy_helper.from_array(np.full((2, 1, 4), 0.25, np.float32), "geom.warp.weight")
    shape = onnx.numpy_helper.from_array(np.array([2, 4, 4], np.int64), "shape")
    nodes = [
        h.make_node("Relu", ["images"], ["a"], name="relu"),
        h.make_node("Transpose", ["a"], ["rows"], name="rows"),
        h.make_node("Gather", ["rows", "geom.warp.index"], ["taps"], name="gather"),
        h.make_node("Reshape", ["taps", "shape"], ["taps3"], name="reshape"),
        h.make_node("MatMul", ["geom.warp.weight", "taps3"], ["warped"], name="weigh"),
        h.make_node("Relu", ["warped"], ["y"], name="after"),
    ]
    graph = h.make_graph(nodes, "g", [x, valid], [y], initializer=[index, weight, shape])
    assert image_region(h.make_model(graph)) == ["relu", "rows"]


def test_int8_path_sits_next_to_the_fp32_file() -> None:
    assert int8_path_for("out/model.onnx") == Path("out/model.int8.onnx")


def test_quantize_never_overwrites_its_input(small_export) -> None:
    with pytest.raises(ExportError, match="never modified"):
        quantize(small_export.onnx, small_export.onnx, FrameReader(np.zeros((1, 4, 160, 160, 3), np.uint8)))


def test_failed_box_match_keeps_no_int8_file(small_export, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    real = reduced_module.int8_parity
    monkeypatch.setattr(
        reduced_module, "int8_parity", lambda *a, **k: real(*a, **k).model_copy(update={"passed": False})
    )
    result = export_int8(
        small_export.onnx,
        tmp_path / "m.int8.onnx",
        options=Int8Options(calib_frames=1, scope="network"),
        comparison=Comparison(frames=1),
        progress=lambda _: None,
    )
    assert result.path is None and list(tmp_path.iterdir()) == []
    assert "FAILED" in result.summary()


@pytest.mark.slow  # a whole export: make test-fast leaves it out
def test_export_refusing_int8_keeps_fp32_and_says_what_to_try(
    small_export, small_bevdet_config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    real = reduced_module.int8_parity
    monkeypatch.setattr(
        reduced_module, "int8_parity", lambda *a, **k: real(*a, **k).model_copy(update={"passed": False})
    )
    out = tmp_path / "m.onnx"
    with pytest.raises(ParityError, match="--int8-float or --int8-scope") as failure:
        export(
            small_export.ckpt,
            out,
            config=small_bevdet_config,
            rig=read_meta(small_export.onnx).rig,
            frames=1,
            int8=Int8Options(calib_frames=1, scope="network"),
            progress=lambda _: None,
        )
    assert "--calib-images" in str(failure.value) and "--force" in str(failure.value)
    assert read_meta(out).parity.passed and not (tmp_path / "m.int8.onnx").exists()


def test_quantizing_an_int8_file_is_refused(small_int8: Int8Result, tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="already quantized"):
        export_int8(
            small_int8.path, tmp_path / "again.onnx", options=Int8Options(calib_frames=1), progress=lambda _: None
        )


@pytest.mark.parametrize(
    "option",
    [["--calib-frames", "3"], ["--int8-scope", "trunk"], ["--int8-float", "bbox_head"]],
    ids=["calib-frames", "int8-scope", "int8-float"],
)
def test_int8_options_need_int8(option: list[str], capsys: pytest.CaptureFixture[str], tmp_path: Path) -> None:
    assert main(["export", "--ckpt", "x.pth", "--out", str(tmp_path / "m.onnx"), *option]) == 2
    assert "--int8" in capsys.readouterr().err


def test_min_kept_is_the_bar_the_int8_file_is_written_at(small_export, small_int8: Int8Result, tmp_path: Path) -> None:
    """The share found again decides against ``min_kept`` (recorded in the metadata, named in the summary), not a fixed 95%."""
    kept = small_int8.parity.top_matched_fraction
    assert (
        small_int8.parity.min_top_matched == 0.95
        and small_int8.parity.top_matched_standard_error is not None
        and kept > 0.0
    )
    options = Int8Options(calib_frames=2, scope="network")
    lower = export_int8(
        small_export.onnx,
        tmp_path / "low.int8.onnx",
        options=options,
        comparison=Comparison(frames=2, min_kept=kept),
        progress=lambda _: None,
    )
    assert lower.path is not None and read_meta(lower.path).parity.min_top_matched == kept
    assert (
        read_meta(lower.path).parity.top_matched_by_score == lower.parity.top_matched_by_score
        and "by the fp32 box's score" in lower.summary()
    )
    assert lower.parity.top_matched_fraction == kept  # the same quantization and frames
    strict = export_int8(
        small_export.onnx,
        tmp_path / "strict.int8.onnx",
        options=options,
        comparison=Comparison(frames=2, min_kept=1.0),
        progress=lambda _: None,
    )
    assert (strict.path is None) == (kept < 1.0) and "need 100%" in strict.summary()


@pytest.mark.parametrize(
    ("option", "named"),
    [
        (["--min-kept", "1.5"], "--min-kept 1.5"),
        (["--min-kept", "0"], "--min-kept 0"),
        (["--compare-frames", "0"], "--compare-frames 0"),
    ],
)
def test_export_refuses_a_comparison_that_cannot_judge(
    option: list[str], named: str, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """Checked before the checkpoint is read (``x.pth`` does not exist)."""
    assert main(["export", "--ckpt", "x.pth", "--out", str(tmp_path / "m.onnx"), "--int8", *option]) == 1
    assert named in capsys.readouterr().err and not list(tmp_path.iterdir())


@pytest.mark.parametrize(
    "option", [["--compare-frames", "8"], ["--min-kept", "0.9"]], ids=["compare-frames", "min-kept"]
)
def test_comparison_options_need_a_reduced_file(
    option: list[str], capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    assert main(["export", "--ckpt", "x.pth", "--out", str(tmp_path / "m.onnx"), *option]) == 2
    assert "need --int8 or --fp16" in capsys.readouterr().err


@pytest.mark.slow  # a whole export: make test-fast leaves it out
def test_export_with_int8_writes_both_files(
    small_export, small_bevdet_config, capsys: pytest.CaptureFixture[str], tmp_path: Path
) -> None:
    """``export(int8=True)`` (``--int8``): the verified fp32 file at ``out``, the int8 file next to it, both in the summary."""
    out = tmp_path / "m.onnx"
    result = export(
        small_export.ckpt,
        out,
        config=small_bevdet_config,
        rig=read_meta(small_export.onnx).rig,
        frames=1,
        int8=Int8Options(calib_frames=1, keep_float=("bbox_head", "img_backbone.conv1")),
        force=True,
    )
    assert read_meta(out).quantization is None and read_meta(out).parity.passed
    assert result.int8 is not None and result.int8.path == tmp_path / "m.int8.onnx"
    int8_meta = read_meta(result.int8.path)
    assert int8_meta.parity.reference == "fp32-onnx"
    assert "bbox_head, img_backbone.conv1 (asked for at export)" in int8_meta.quantization.scope
    conv1 = next(
        n.name
        for n in _named(out).graph.node
        if n.op_type == "Conv" and n.input[1] == "model.img_backbone.conv1.weight"
    )
    layers = _int8_layers(onnx.load(str(result.int8.path)))
    assert layers and conv1 not in layers
    summary = result.summary()
    assert "parity vs PyTorch" in summary and "top-50 boxes matched" in summary
    printed = capsys.readouterr().out
    assert "[4/5] verifying" in printed and "int8 [2/3]" in printed


@pytest.mark.slow
def test_full_bevdet_quantizes_its_network(bevdet_export, tmp_path: Path) -> None:
    """The full-size FisheyeBEVDet (two calibration frames): every weighted layer in int8 but the head's (its shared and first heatmap convolutions aside)."""
    result = export_int8(
        bevdet_export.onnx,
        tmp_path / "bevdet.int8.onnx",
        options=Int8Options(calib_frames=2, scope="network"),
        comparison=Comparison(frames=1),
        force=True,
        progress=lambda _: None,
    )
    model, region = _region_names(result.path)
    layers = _int8_layers(model)
    assert len(layers & region) >= 20 and len(layers - region) >= 8  # trunk, and the depth net, BEV encoder and neck
    assert Detector(result.path, threads=2).info.meta.parity.reference == "fp32-onnx"


# -- 7-bit weights: the same integers on CPUs with and without VNNI ----------------------------------

AVX2_ONLY = CpuInfo("an AVX2-only CPU", frozenset({"sse2", "avx", "avx2", "fma"}))
WITH_VNNI = CpuInfo("a VNNI CPU", frozenset({"sse2", "avx2", "avx512f", "avx512_vnni"}))


def _int8_weights(model: onnx.ModelProto) -> list[np.ndarray]:
    inits = {i.name: i for i in model.graph.initializer}
    return [
        numpy_helper.to_array(inits[n.input[0]])
        for n in model.graph.node
        if n.op_type == "DequantizeLinear"
        and n.input[0] in inits
        and inits[n.input[0]].data_type == onnx.TensorProto.INT8
    ]


def test_int8_weights_are_7_bit_so_pairs_of_products_fit_int16(small_int8: Int8Result) -> None:
    """vpmaddubsw (x86 without VNNI) adds two u8 x s8 products in saturating int16: 2 x 255 x 64 fits, 2 x 255 x 127 does not."""
    model = onnx.load(str(small_int8.path))
    weights = _int8_weights(model)
    assert len(weights) == len(_int8_layers(model))
    assert (
        max(int(np.abs(w.astype(np.int32)).max()) for w in weights) == WEIGHT_QMAX[7] == 64
    )  # the 7-bit range, used to its end
    assert 2 * 255 * WEIGHT_QMAX[7] <= np.iinfo(np.int16).max < 2 * 255 * WEIGHT_QMAX[8]
    assert small_int8.meta.quantization is not None and small_int8.meta.quantization.weight_bits == 7
    assert read_meta(small_int8.path).quantization == small_int8.meta.quantization
    assert "7-bit weights" in small_int8.summary()


def _dequantize_graph(weight: np.ndarray, zero_point: np.ndarray) -> onnx.ModelProto:
    inits = [
        numpy_helper.from_array(weight, "conv.weight_quantized"),
        numpy_helper.from_array(np.ones(len(weight), np.float32), "s"),
        numpy_helper.from_array(zero_point, "zp"),
    ]
    node = onnx.helper.make_node("DequantizeLinear", ["conv.weight_quantized", "s", "zp"], ["w"], axis=0)
    out = onnx.helper.make_tensor_value_info("w", onnx.TensorProto.FLOAT, list(weight.shape))
    return onnx.helper.make_model(onnx.helper.make_graph([node], "g", [], [out], inits))


def test_7_bit_weights_leave_other_constants_at_8_bits(tmp_path: Path) -> None:
    """A Linear (MatMul + bias Add): ORT's reduce_range would cut the bias's u8 constant to [0, 127] too."""
    from onnxruntime.quantization import CalibrationDataReader, QuantFormat, QuantType, quantize_static

    rng = np.random.default_rng(0)
    inits = [
        numpy_helper.from_array(rng.normal(size=(8, 6)).astype(np.float32), "W"),
        numpy_helper.from_array(rng.uniform(0.1, 1.0, size=6).astype(np.float32), "b"),
    ]
    graph = onnx.helper.make_graph(
        [
            onnx.helper.make_node("MatMul", ["x", "W"], ["h"], name="mm"),
            onnx.helper.make_node("Add", ["h", "b"], ["y"], name="add"),
        ],
        "linear",
        [onnx.helper.make_tensor_value_info("x", onnx.TensorProto.FLOAT, [4, 8])],
        [onnx.helper.make_tensor_value_info("y", onnx.TensorProto.FLOAT, [4, 6])],
        inits,
    )
    model = onnx.helper.make_model(graph, opset_imports=[onnx.helper.make_opsetid("", 18)])
    assert eight_bit_constants(model, ["mm", "add"]) == {
        "b": [{"reduce_range": False}]
    }  # the weight keeps reduce_range
    onnx.save(model, str(tmp_path / "linear.onnx"))

    class Frames(CalibrationDataReader):
        def __init__(self) -> None:
            self.feeds = iter([{"x": rng.normal(size=(4, 8)).astype(np.float32)} for _ in range(4)])

        def get_next(self) -> dict[str, np.ndarray] | None:
            return next(self.feeds, None)

    def quantized_constants(overrides: dict) -> dict[str, np.ndarray]:
        out = tmp_path / "linear.int8.onnx"
        quantize_static(
            str(tmp_path / "linear.onnx"),
            str(out),
            Frames(),
            quant_format=QuantFormat.QDQ,
            op_types_to_quantize=["MatMul", "Add"],
            activation_type=QuantType.QUInt8,
            weight_type=QuantType.QInt8,
            per_channel=True,
            reduce_range=True,
            extra_options={"WeightSymmetric": True, "TensorQuantOverrides": overrides},
        )
        return {
            i.name: numpy_helper.to_array(i)
            for i in onnx.load(str(out)).graph.initializer
            if i.data_type in (onnx.TensorProto.INT8, onnx.TensorProto.UINT8)
        }

    plain = quantized_constants({})
    kept = quantized_constants(eight_bit_constants(model, ["mm", "add"]))
    bias = next(name for name, v in kept.items() if v.dtype == np.uint8 and v.size == 6)
    assert plain[bias].max() == 127 and kept[bias].max() == 255  # the bias keeps its 8 bits
    weight = next(name for name, v in kept.items() if v.dtype == np.int8 and v.size == 48)
    assert np.abs(kept[weight].astype(np.int32)).max() == WEIGHT_QMAX[7]  # the weight does not


def test_check_weight_range_names_a_weight_beyond_7_bits() -> None:
    check_weight_range(_dequantize_graph(np.array([[64, -64], [3, 0]], np.int8), np.zeros(2, np.int8)))
    with pytest.raises(
        ExportError, match=r"conv.weight_quantized spans \[-100, 3\].*expected 7-bit weights, \[-64, 64\]"
    ):
        check_weight_range(_dequantize_graph(np.array([[1, -100], [3, 0]], np.int8), np.zeros(2, np.int8)))
    check_weight_range(_dequantize_graph(np.array([[1, -100], [3, 0]], np.int8), np.zeros(2, np.int8)), weight_bits=8)
    with pytest.raises(ExportError, match=r"zero point \[0, 5\]"):
        check_weight_range(_dequantize_graph(np.array([[1, -10], [3, 0]], np.int8), np.array([0, 5], np.int8)))


def test_8_bit_weights_on_request(small_export, tmp_path: Path) -> None:
    result = export_int8(
        small_export.onnx,
        tmp_path / "m.int8.onnx",
        options=Int8Options(calib_frames=1, scope="network", weight_bits=8),
        comparison=Comparison(frames=1),
        force=True,
        progress=lambda _: None,
    )
    assert (
        result.path is not None and result.meta.quantization is not None and result.meta.quantization.weight_bits == 8
    )
    assert (
        max(int(np.abs(w.astype(np.int32)).max()) for w in _int8_weights(onnx.load(str(result.path)))) == WEIGHT_QMAX[8]
    )
    with pytest.raises(ExportError, match="weight_bits 6"):
        Int8Options(calib_frames=1, weight_bits=6)


def test_previous_keywords_still_work_with_a_deprecation_warning(small_export, tmp_path: Path) -> None:
    """``export_int8(calib_frames=..., frames=...)`` as the previous release took them: the same options, and a warning."""
    with pytest.warns(DeprecationWarning, match="Int8Options"):
        result = export_int8(
            small_export.onnx,
            tmp_path / "m.int8.onnx",
            calib_frames=1,
            frames=1,
            weight_bits=8,
            scope="network",
            force=True,
            progress=lambda _: None,
        )
    assert (
        result.meta.quantization.calibration_frames == 1
        and result.meta.quantization.weight_bits == 8
        and result.parity.frames == 1
    )
    with pytest.raises(TypeError, match="calib_frame"):
        export_int8(small_export.onnx, tmp_path / "n.int8.onnx", calib_frame=1)


def test_saturation_warning_only_for_8_bit_int8_files_on_x86_without_vnni(small_int8: Int8Result) -> None:
    meta = small_int8.meta
    assert meta.quantization is not None
    old = meta.model_copy(update={"quantization": meta.quantization.model_copy(update={"weight_bits": None})})
    cpu = ["CPUExecutionProvider"]
    message = int8_saturation_warning(old, cpu, AVX2_ONLY)
    assert message is not None and "8-bit weights" in message and "without VNNI" in message and "export" in message
    assert int8_saturation_warning(meta, cpu, AVX2_ONLY) is None  # 7-bit weights never saturate
    assert int8_saturation_warning(old, cpu, WITH_VNNI) is None
    assert int8_saturation_warning(old, ["CUDAExecutionProvider", "CPUExecutionProvider"], AVX2_ONLY) is None
    assert int8_saturation_warning(old, cpu, CpuInfo("an Arm CPU", frozenset())) is None  # flags unknown: nothing said
    skylake_sp = CpuInfo("AVX-512 without VNNI", frozenset({"sse2", "avx2", "avx512f", "avx512bw"}))
    assert int8_saturation_warning(old, cpu, skylake_sp) is not None
    before_avx2 = CpuInfo("SSE4 only", frozenset({"sse2", "ssse3", "sse4_1", "sse4_2", "avx"}))
    assert (
        int8_saturation_warning(old, cpu, before_avx2) is None
    )  # SSE2 kernels widen to int16 before multiplying: exact
    fp32 = meta.model_copy(update={"quantization": None})
    assert int8_saturation_warning(fp32, cpu, AVX2_ONLY) is None
    half = meta.model_copy(update={"quantization": Quantization(mode="fp16", scope="network")})
    assert int8_saturation_warning(half, cpu, AVX2_ONLY) is None


def test_detector_warns_about_an_8_bit_int8_file_on_a_cpu_without_vnni(
    small_int8: Int8Result, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    """Files written before weights were limited to 7 bits record no ``weight_bits``; the CPU read is an AVX2-only one's flags."""
    meta = small_int8.meta
    assert meta.quantization is not None
    proto = onnx.load(str(small_int8.path))
    set_metadata(
        proto, meta.model_copy(update={"quantization": meta.quantization.model_copy(update={"weight_bits": None})})
    )
    old = save_model(proto, tmp_path / "old.int8.onnx")
    import fisheye_infer.runtime.detector as detector_module

    monkeypatch.setattr(detector_module, "cpu_info", lambda: AVX2_ONLY)
    with caplog.at_level("WARNING", logger="fisheye_infer"):
        Detector(old, threads=1, warmup=False)
        Detector(small_int8.path, threads=1, warmup=False)
    warnings = [r.getMessage() for r in caplog.records if "VNNI" in r.getMessage()]
    assert len(warnings) == 1 and meta.model_id in warnings[0]  # the 8-bit file only


def test_schema_1_metadata_reads_as_the_split_reports(small_export, small_int8: Int8Result) -> None:
    """Files of schema 1 carry one parity type for every file, its unused fields null; they read as the type they describe."""
    import json

    from fisheye_infer.runtime.artifact import ParityReport, ReducedParityReport, parse_meta

    fp32 = json.loads(read_meta(small_export.onnx).model_dump_json())
    fp32_v1 = {
        **fp32,
        "schema_version": 1,
        "parity": {
            **fp32["parity"],
            "top_matched_fraction": None,
            "min_top_matched": None,
            "evaluated_with": None,
            "replayed": None,
        },
    }
    assert parse_meta(json.dumps(fp32_v1)).parity == read_meta(small_export.onnx).parity
    int8 = json.loads(small_int8.meta.model_dump_json())
    reduced = int8["parity"]
    int8["quantization"] = {k: v for k, v in int8["quantization"].items() if k not in ("float_modules", "search")}
    int8_v1 = {
        **int8,
        "schema_version": 1,
        "parity": {
            **{k: v for k, v in reduced.items() if k != "match_radius_m"},
            "tolerance_box_m": 0.5,
            "tolerance_score": 1.0,
            "order_equal": False,
            "pytorch_float32": None,
            "selection_valid": None,
            "tie_swaps": 0,
            "tie_substitutions": 0,
            "written_equals_checked": None,
            "tolerance_rank_score": None,
            "min_top_matched": None,
        },
    }
    migrated = parse_meta(json.dumps(int8_v1))
    assert isinstance(migrated.parity, ReducedParityReport) and isinstance(
        read_meta(small_export.onnx).parity, ParityReport
    )
    assert migrated.schema_version == 3 and migrated.parity == small_int8.parity  # 0.95: the bar before it was recorded
    assert migrated.quantization is not None and migrated.quantization.search is None


def test_schema_2_metadata_reads_without_the_search_record(small_int8: Int8Result) -> None:
    """Files of schema 2 have neither the float modules nor the int8 search's record; they read as schema 3."""
    import json

    from fisheye_infer.runtime.artifact import parse_meta

    int8 = json.loads(small_int8.meta.model_dump_json())
    int8["quantization"] = {k: v for k, v in int8["quantization"].items() if k not in ("float_modules", "search")}
    migrated = parse_meta(json.dumps({**int8, "schema_version": 2}))
    assert migrated.schema_version == 3 and migrated.quantization is not None
    assert migrated.quantization.float_modules == () and migrated.quantization.search is None
    assert migrated.model_copy(update={"quantization": small_int8.meta.quantization}) == small_int8.meta
