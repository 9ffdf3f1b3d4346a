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

from fisheye_infer.artifact import METADATA_KEY, OUTPUTS, read_meta
from fisheye_infer.errors import ArtifactError, CheckpointError, ExportError, ParityError
from fisheye_infer.export import exporter as exporter_module
from fisheye_infer.export.architectures import infer_architecture
from fisheye_infer.export.exporter import export, verification_frames
from fisheye_infer.export.graph import get_metadata
from fisheye_infer.export.verify import compare_outputs, run_onnx, run_torch
from fisheye_infer.models import load_model
from fisheye_infer.rig import Rig, default_rig
from fisheye_infer.synth import resized_rig


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
    assert "geom.grid" in names
    expected = {"fisheye-bevdet": "geom.pool.cell_rows", "fisheye-petr": "geom.petr.key_pos"}[exported.arch]
    assert expected in meta.geometry_initializers
    assert not any(n.op_type.startswith("Scatter") for n in model.graph.node)
    assert {i.name for i in model.graph.input} == {"images", "camera_valid"}


def test_metadata_describes_the_model(exported, rig: Rig) -> None:
    meta = read_meta(exported.onnx)
    assert meta.architecture == exported.arch and meta.schema_version == 1
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


@pytest.mark.parametrize("threads", [1, 2])
def test_parity_with_pytorch(exported, rig: Rig, threads: int) -> None:
    """Every PyTorch box has its ONNX counterpart: same label and validity, box within 1e-3 m, score
    within 1e-4, at 1 and 2 threads, batch 2. Proposals whose ranking keys are equal to float
    precision may trade places; such swaps must be rare."""
    model, _ = load_model(exported.arch, exported.ckpt)
    frames = verification_frames(rig, 2, seed=11)
    valid = np.ones(frames.shape[:2], bool)
    diff = compare_outputs(run_torch(model, frames, valid), run_onnx(exported.onnx, frames, valid, threads))
    assert diff.unmatched == 0 and diff.valid_equal
    assert diff.box <= 1e-3 and diff.score <= 1e-4
    assert diff.swaps <= 4


def test_parity_comparison_catches_a_wrong_box(exported, rig: Rig) -> None:
    model, _ = load_model(exported.arch, exported.ckpt)
    frames = verification_frames(rig, 1, seed=12)
    valid = np.ones(frames.shape[:2], bool)
    ref = run_torch(model, frames, valid)
    top = int(ref[1][0].argmax())  # the most confident box: no tie can excuse it
    got = [a.copy() for a in ref]
    got[0][0, top, 0] += 0.01  # 1 cm off
    assert compare_outputs(ref, got).unmatched == 1
    got = [a.copy() for a in ref]
    got[2][0, top] = (got[2][0, top] + 1) % 6  # another label
    assert compare_outputs(ref, got).unmatched == 1


def test_degraded_mode_matches_pytorch(bevdet_export, rig: Rig) -> None:
    model, _ = load_model(bevdet_export.arch, bevdet_export.ckpt)
    frames = verification_frames(rig, 1, seed=5)
    valid = np.array([[True, False, True, False]])
    got = run_onnx(bevdet_export.onnx, frames, valid, 2)
    diff = compare_outputs(run_torch(model, frames, valid), got)
    assert diff.unmatched == 0 and diff.box <= 1e-3 and diff.score <= 1e-4
    full = run_onnx(bevdet_export.onnx, frames, np.ones_like(valid), 2)
    assert not np.allclose(got[1], full[1])  # the missing cameras changed the answer


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


def test_a_graph_that_disagrees_with_pytorch_is_refused(small_ckpt: Path, small_bevdet_config, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    _broken_trace(monkeypatch)
    out = tmp_path / "small.onnx"
    with pytest.raises(ParityError, match="no file written") as info:
        export(small_ckpt, out, config=small_bevdet_config, rig=SMALL_RIG, progress=lambda _: None)
    assert "FAILED" in str(info.value)
    assert list(tmp_path.iterdir()) == []
    result = export(small_ckpt, out, config=small_bevdet_config, rig=SMALL_RIG, force=True, progress=lambda _: None)
    parity = read_meta(out).parity
    assert out.is_file() and result.path == out and not parity.passed
    assert parity.max_box_abs_diff_m > 1e-3 or parity.unmatched > 0


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


def test_config_that_does_not_fit_the_checkpoint_is_named(small_ckpt: Path, small_bevdet_config, tmp_path: Path) -> None:
    wider = small_bevdet_config.replace(head={"hidden_channel": 48})
    with pytest.raises(CheckpointError, match=r"shape mismatches(.|\n)*model \[48(.|\n)*the config the checkpoint was trained with"):
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
    doc = get_metadata(model)[METADATA_KEY].replace('"schema_version":1', '"schema_version":7')
    for p in model.metadata_props:
        if p.key == METADATA_KEY:
            p.value = doc
    onnx.save(model, str(bare))
    with pytest.raises(ArtifactError, match="schema_version 7 is not supported"):
        read_meta(bare)
