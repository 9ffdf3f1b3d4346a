"""The exported artifact: one self-contained file, standard ops, named geometry, metadata, parity."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import onnx
import pytest
from onnx import numpy_helper

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import Rig, default_rig
from fisheye_infer.errors import ArtifactError, CheckpointError, ExportError, ParityError
from fisheye_infer.export import exporter as exporter_module
from fisheye_infer.export.exporter import export, infer_architecture, verification_frames
from fisheye_infer.export.graph import get_metadata
from fisheye_infer.export.verify import (
    FLOOR_BOX_M,
    FLOOR_SCORE,
    PROBE,
    SLACK,
    Reference,
    checked_graph,
    compare_run,
    run_onnx,
    verify,
)
from fisheye_infer.models import load_model
from fisheye_infer.runtime.artifact import METADATA_KEY, OUTPUTS, read_meta
from fisheye_infer.scenes.render import resized_rig


def test_one_self_contained_file_with_standard_ops(exported) -> None:
    folder = exported.onnx.parent
    assert [p.name for p in folder.iterdir() if p.name.startswith(exported.onnx.name)] == [exported.onnx.name]
    model = onnx.load(str(exported.onnx))
    onnx.checker.check_model(model)
    assert {n.domain for n in model.graph.node} <= {"", "ai.onnx"}
    assert max(o.version for o in model.opset_import if o.domain in ("", "ai.onnx")) >= 18
    assert [o.name for o in model.graph.output] == list(OUTPUTS)
    images = model.graph.input[0].type.tensor_type.shape.dim
    assert images[0].dim_param and [d.dim_value for d in images[1:]] == [4, 800, 800, 3]


def test_geometry_is_baked_as_named_initializers(exported) -> None:
    model = onnx.load(str(exported.onnx))
    names = {i.name for i in model.graph.initializer}
    meta = read_meta(exported.onnx)
    assert set(meta.geometry_initializers) <= names
    assert {"geom.warp.index", "geom.warp.weight"} <= names
    assert not any(n.op_type == "GridSample" for n in model.graph.node)  # the warp is its precomputed taps
    expected = {"fisheye-bevdet": "geom.pool.cell_rows", "fisheye-petr": "geom.petr.key_pos"}[exported.arch]
    assert expected in meta.geometry_initializers
    assert not any(n.op_type.startswith("Scatter") for n in model.graph.node)
    assert {i.name for i in model.graph.input} == {"images", "camera_valid"}


def test_normalisation_division_is_in_the_first_convolution(exported) -> None:
    """Only the mean's Sub stands between the images and the first convolution (its Div is in the weights),
    and it subtracts a whole row's constant (W x 3 values), not three values broadcast channels-last."""
    model = onnx.load(str(exported.onnx))
    nodes = [n for n in model.graph.node if n.op_type not in ("Shape", "Constant")]
    ops = [n.op_type for n in nodes]
    first_conv = ops.index("Conv")
    assert "Sub" in ops[:first_conv] and "Div" not in ops[:first_conv]
    sub = nodes[ops.index("Sub")]
    mean = {i.name: i for i in model.graph.initializer}[sub.input[1]]
    assert list(mean.dims) == [800 * 3]


def test_metadata_describes_the_model(exported, rig: Rig) -> None:
    meta = read_meta(exported.onnx)
    assert meta.architecture == exported.arch and meta.schema_version == 3
    assert meta.cameras == tuple(rig.names) and meta.rig_hash == rig.hash and meta.rig == rig
    assert meta.image_size == (800, 800) and meta.colour_order == "BGR"
    assert meta.normalisation.mean == (123.675, 116.28, 103.53)
    assert meta.classes == ("Car", "Van", "Truck", "Bus", "Pedestrian", "Cyclist")
    assert meta.num_boxes == {"fisheye-bevdet": 200, "fisheye-petr": 300}[exported.arch]
    assert meta.tools["torch"] == torch.__version__ and meta.checkpoint_sha256
    assert meta.parity is not None and meta.parity.passed and meta.parity.threads == (1, 2)


def test_loads_in_onnxruntime_without_warnings(exported) -> None:
    code = (
        "import onnxruntime as ort; o = ort.SessionOptions(); o.log_severity_level = 1; "
        f"ort.InferenceSession({str(exported.onnx)!r}, o, providers=['CPUExecutionProvider'])"
    )
    result = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr
    assert "[W:" not in result.stderr and "[E:" not in result.stderr, result.stderr[-2000:]


def test_export_self_check_passed_on_the_kit_checkpoint(exported) -> None:
    """The kit's realistic activations tie heatmap cells; the self-check still passes, and says how."""
    p = exported.result.parity
    assert (
        p.passed and p.reference == "pytorch-float64" and p.threads == (1, 2) and p.frames == 2
    )  # one rendered + --verify-images
    assert p.selection_valid and p.labels_equal and p.valid_equal and p.unmatched == 0 and p.written_equals_checked
    assert p.max_rank_score_abs_diff <= p.tolerance_rank_score and p.max_box_abs_diff_m <= p.tolerance_box_m
    dense, box, _ = p.pytorch_float32  # the tolerances are set by float32's own drift, nothing else
    assert p.tolerance_box_m == max(FLOOR_BOX_M, SLACK * box) and p.tolerance_rank_score == max(
        FLOOR_SCORE, SLACK * dense
    )
    assert "PASSED" in exported.result.summary() and "top-k choice" in exported.result.summary()


#: The cameras the reference frame feeds: front and right (degraded mode); the export's own self-check
#: has every camera.
DEGRADED = np.array([[True, False, True, False]])


@pytest.fixture(scope="module")
def references() -> dict[str, Reference]:
    """By architecture: the float64 model and PyTorch float32 on a frame the export did not check, in
    degraded mode, built once for the parity tests and the refusals below (a full-size float64 forward
    takes a minute)."""
    return {}


def reference_of(exported, references: dict[str, Reference], rig: Rig) -> Reference:
    """The reference of ``exported``'s architecture, built at its first use."""
    if exported.arch not in references:
        model, _ = load_model(exported.arch, exported.ckpt)
        references[exported.arch] = Reference(model, verification_frames(rig, 1, seed=11), DEGRADED)
    return references[exported.arch]


@pytest.fixture(scope="module")
def reference(exported, references: dict[str, Reference], rig: Rig) -> Reference:
    return reference_of(exported, references, rig)


@pytest.fixture(scope="module")
def checked(exported, tmp_path_factory: pytest.TempPathFactory) -> Path:
    return checked_graph(exported.onnx, tmp_path_factory.mktemp("checked") / f"{exported.arch}.onnx")


@pytest.mark.parametrize("threads", [1, 2])
def test_parity_with_pytorch_on_another_frame(reference: Reference, checked: Path, threads: int) -> None:
    """Dense scores, a legitimate top-k, and every box at the graph's own choice, within the
    tolerances that PyTorch float32's own drift from float64 sets, with two cameras missing."""
    got = run_onnx(checked, reference.frames, reference.valid, threads, PROBE)
    diff = compare_run(reference, got)
    tol = reference.float32_errors.tolerances()
    assert diff.selection_valid and diff.labels_equal and diff.valid_equal, diff.notes
    assert diff.errors.rank_score <= tol.rank_score and diff.mismatched(tol) == 0
    assert diff.passed(tol)


def test_parity_check_catches_a_wrong_box_and_a_wrong_choice(reference: Reference, checked: Path) -> None:
    got = run_onnx(checked, reference.frames, reference.valid, 2, PROBE)
    tol = reference.float32_errors.tolerances()
    assert compare_run(reference, got).passed(tol)
    top = int(got["scores"][0].argmax())
    moved = {k: v.copy() for k, v in got.items()}
    moved["boxes"][0, top, 0] += 0.5  # half a metre off
    assert compare_run(reference, moved).mismatched(tol) == 1
    relabelled = {k: v.copy() for k, v in got.items()}
    relabelled["labels"][0, top] = (relabelled["labels"][0, top] + 1) % 6
    assert compare_run(reference, relabelled).mismatched(tol) == 1
    skipped = {k: v.copy() for k, v in got.items()}
    skipped["rank_indices"][0, 0] = int(np.argmin(skipped["rank_scores"][0]))  # the best proposal left out
    diff = compare_run(reference, skipped)
    assert not diff.selection_valid and "left out beats a chosen one" in diff.notes[0]


def test_self_check_fails_on_a_perturbed_weight(
    bevdet_export, references: dict[str, Reference], rig: Rig, tmp_path: Path
) -> None:
    proto = onnx.load(str(bevdet_export.onnx))
    init = next(i for i in proto.graph.initializer if i.name.endswith("bbox_head.shared_conv.weight"))
    w = numpy_helper.to_array(init).copy()
    w[0, 0, 1, 1] += 0.05  # one weight of 589,824, moved by a quarter of its spread
    init.CopyFrom(numpy_helper.from_array(w, init.name))
    bad = tmp_path / "perturbed.onnx"
    onnx.save(proto, str(bad))
    report = verify(bad, reference_of(bevdet_export, references, rig), threads=(2,))
    assert not report.passed
    assert report.max_rank_score_abs_diff > report.tolerance_rank_score or report.unmatched > 0


def test_self_check_fails_on_the_interleaved_sine_layout(
    petr_export, references: dict[str, Reference], rig: Rig, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """A FisheyePETR file whose key position embedding was built with interleaved sin/cos (the layout
    the official code does not use) is refused, though everything else in it is right."""
    from fisheye_infer.export.graph import REBAKE_WEIGHTS_KEY, decode_arrays, replace_initializers, save_model
    from fisheye_infer.geometry import petr as petr_geometry
    from fisheye_infer.geometry.kinds import tables_for
    from fisheye_infer.geometry.tables import PETR_KEY_POS

    def interleaved(a: np.ndarray, dim_t: np.ndarray) -> np.ndarray:
        p = a[..., None] / dim_t
        return np.stack((np.sin(p[..., 0::2]), np.cos(p[..., 1::2])), axis=-1).reshape(*a.shape, -1)

    proto = onnx.load(str(petr_export.onnx))
    weights = decode_arrays(get_metadata(proto)[REBAKE_WEIGHTS_KEY])
    monkeypatch.setattr(petr_geometry, "_blocked_sin_cos", interleaved)
    tables = tables_for(rig, read_meta(petr_export.onnx).geometry, weights)
    monkeypatch.undo()
    replace_initializers(proto, {PETR_KEY_POS: tables[PETR_KEY_POS]})
    bad = save_model(proto, tmp_path / "interleaved.onnx")
    report = verify(bad, reference_of(petr_export, references, rig), threads=(2,))
    assert not report.passed and report.max_box_abs_diff_m > report.tolerance_box_m


def test_the_missing_cameras_change_the_answer(reference: Reference, checked: Path) -> None:
    """The parity tests above run in degraded mode: with every camera the same frame gives another answer."""
    full = run_onnx(checked, reference.frames, np.ones_like(reference.valid), 2)
    assert not np.allclose(run_onnx(checked, reference.frames, reference.valid, 2)["scores"], full["scores"])


def test_architecture_is_inferred_from_keys(bevdet_export, petr_export) -> None:
    from fisheye_infer.models import load_checkpoint

    assert infer_architecture(load_checkpoint(bevdet_export.ckpt)[0]) == "fisheye-bevdet"
    assert infer_architecture(load_checkpoint(petr_export.ckpt)[0]) == "fisheye-petr"
    with pytest.raises(ExportError, match="cannot tell the architecture"):
        infer_architecture({"backbone.conv1.weight": None})


# -- refusals, on a reduced configuration (seconds, not minutes) ------------------------------

SMALL_RIG = resized_rig(default_rig(), 0.2)  # 160 x 160


@pytest.fixture(scope="module")
def small_ckpt(small_export) -> Path:
    """The seeded checkpoint behind ``small_export`` (reduced FisheyeBEVDet, rig resized to 160x160)."""
    return small_export.ckpt


def test_small_export_passes(small_export) -> None:
    result = small_export.result
    assert result.parity.passed and result.path.is_file() and result.parity.threads == (1, 2)
    assert 0 < result.geometry_bytes < result.initializer_bytes < result.file_bytes
    summary = result.summary()
    assert "parity vs PyTorch" in summary and "initializers" in summary and "took" in summary


def _broken_trace(monkeypatch: pytest.MonkeyPatch) -> None:
    """The traced graph's box-centre bias moves by 0.5 BEV cells: a file that disagrees with PyTorch."""
    real = exporter_module.trace_to_onnx

    def broken(*args, **kwargs) -> onnx.ModelProto:
        proto = real(*args, **kwargs)
        init = next(i for i in proto.graph.initializer if i.name.endswith("prediction_heads.0.center.1.bias"))
        init.CopyFrom(numpy_helper.from_array(numpy_helper.to_array(init) + np.float32(0.5), init.name))
        return proto

    monkeypatch.setattr(exporter_module, "trace_to_onnx", broken)


@pytest.mark.slow  # a whole export: make test-fast leaves it out
def test_a_graph_that_disagrees_with_pytorch_is_refused(
    small_ckpt: Path, small_bevdet_config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    _broken_trace(monkeypatch)
    out = tmp_path / "small.onnx"
    with pytest.raises(ParityError, match="no file written") as info:
        export(
            small_ckpt, out, config=small_bevdet_config, rig=SMALL_RIG, progress=lambda _: None, frames=1, threads=(1,)
        )
    assert "FAILED" in str(info.value)
    assert list(tmp_path.iterdir()) == []
    result = export(
        small_ckpt,
        out,
        config=small_bevdet_config,
        rig=SMALL_RIG,
        force=True,
        progress=lambda _: None,
        frames=1,
        threads=(1,),
    )
    parity = read_meta(out).parity
    assert out.is_file() and result.path == out and not parity.passed
    assert parity.max_box_abs_diff_m > parity.tolerance_box_m or parity.unmatched > 0


def test_rig_of_another_image_size_is_refused(small_ckpt: Path, small_bevdet_config, tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="image is 800x800, model expects 160x160"):
        export(small_ckpt, tmp_path / "x.onnx", config=small_bevdet_config, rig=default_rig(), progress=lambda _: None)
    assert list(tmp_path.iterdir()) == []


def test_checkpoint_missing_a_key_is_named(small_ckpt: Path, small_bevdet_config, tmp_path: Path) -> None:
    ckpt = torch.load(small_ckpt, weights_only=True)
    del ckpt["state_dict"]["bbox_head.heatmap_head.1.bias"]
    bad = tmp_path / "bad.pth"
    torch.save(ckpt, bad)
    with pytest.raises(CheckpointError, match=r"bbox_head\.heatmap_head\.1\.bias"):
        export(bad, tmp_path / "x.onnx", config=small_bevdet_config, rig=SMALL_RIG, progress=lambda _: None)


def test_config_that_does_not_fit_the_checkpoint_is_named(
    small_ckpt: Path, small_bevdet_config, tmp_path: Path
) -> None:
    wider = small_bevdet_config.replace(head={"hidden_channel": 48})
    with pytest.raises(
        CheckpointError, match=r"shape mismatches(.|\n)*model \[48(.|\n)*the config the checkpoint was trained with"
    ):
        export(small_ckpt, tmp_path / "x.onnx", config=wider, rig=SMALL_RIG, progress=lambda _: None)


def test_wrong_architecture_is_refused(small_ckpt: Path, tmp_path: Path) -> None:
    with pytest.raises(ExportError, match="--arch fisheye-petr: checkpoint small.pth holds a fisheye-bevdet model"):
        export(small_ckpt, tmp_path / "x.onnx", arch="fisheye-petr", rig=SMALL_RIG, progress=lambda _: None)
    with pytest.raises(ExportError, match="cannot be exported"):
        export(small_ckpt, tmp_path / "x.onnx", arch="fisheye-lss", rig=SMALL_RIG, progress=lambda _: None)


def test_metadata_is_required_and_checked(bevdet_export, tmp_path: Path) -> None:
    model = onnx.load(str(bevdet_export.onnx))
    del model.metadata_props[:]
    bare = tmp_path / "bare.onnx"
    onnx.save(model, str(bare))
    with pytest.raises(ArtifactError, match="no 'fisheye_infer' metadata"):
        read_meta(bare)
    model = onnx.load(str(bevdet_export.onnx))
    doc = get_metadata(model)[METADATA_KEY].replace('"schema_version":3', '"schema_version":7')
    for p in model.metadata_props:
        if p.key == METADATA_KEY:
            p.value = doc
    onnx.save(model, str(bare))
    with pytest.raises(ArtifactError, match="schema_version 7 is not supported"):
        read_meta(bare)
