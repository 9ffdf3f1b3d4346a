"""``fisheye-infer triton``: the model repository, checked by parsing config.pbtxt with Triton's own ModelConfig."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fisheye_infer.cli import main
from fisheye_infer.deploy.triton.python_backend import MODEL_PY, TritonPythonModel, check_request
from fisheye_infer.deploy.triton.repository import (
    TritonOptions,
    model_config,
    model_name,
    render_pbtxt,
    write_repository,
)
from fisheye_infer.errors import ArtifactError, ExportError, FrameError
from fisheye_infer.runtime.artifact import METADATA_KEY, read_meta

pytest.importorskip("tritonclient.grpc", reason="the [triton] extra ships Triton's ModelConfig protobuf")
from google.protobuf import json_format, text_format  # noqa: E402
from tritonclient.grpc import model_config_pb2  # noqa: E402


def _parse(path: Path) -> model_config_pb2.ModelConfig:
    return text_format.Parse(path.read_text(), model_config_pb2.ModelConfig())


def test_repository_layout_and_config_parse_into_triton_modelconfig(small_export, tmp_path: Path) -> None:
    target = write_repository(
        small_export.onnx,
        tmp_path / "repo",
        TritonOptions(max_batch_size=4, preferred_batch_sizes=(2, 4), instances=2, kind="cpu", threads=1),
    )
    assert target == tmp_path / "repo" / model_name(small_export.onnx)
    assert (target / "1" / "model.onnx").read_bytes() == Path(small_export.onnx).read_bytes()
    config = _parse(target / "config.pbtxt")
    assert config.name == target.name and config.backend == "onnxruntime" and config.max_batch_size == 4
    inputs = {i.name: (model_config_pb2.DataType.Name(i.data_type), list(i.dims)) for i in config.input}
    assert inputs == {"images": ("TYPE_UINT8", [4, 160, 160, 3]), "camera_valid": ("TYPE_BOOL", [4])}
    outputs = {o.name: (model_config_pb2.DataType.Name(o.data_type), list(o.dims)) for o in config.output}
    k = read_meta(small_export.onnx).num_boxes
    assert outputs == {
        "boxes": ("TYPE_FP32", [k, 7]),
        "scores": ("TYPE_FP32", [k]),
        "labels": ("TYPE_INT64", [k]),
        "valid": ("TYPE_BOOL", [k]),
    }
    assert (
        list(config.dynamic_batching.preferred_batch_size) == [2, 4]
        and config.dynamic_batching.max_queue_delay_microseconds == 5000
    )
    (group,) = config.instance_group
    assert group.count == 2 and group.kind == model_config_pb2.ModelInstanceGroup.KIND_CPU
    assert config.parameters["intra_op_thread_count"].string_value == "1"
    stored = json.loads(config.parameters[METADATA_KEY].string_value)
    assert stored == json.loads(read_meta(small_export.onnx).model_dump_json())  # the whole metadata document, intact


def test_text_and_json_forms_are_the_same_modelconfig(small_export) -> None:
    """The dict the KServe stand-in answers with and the text Triton reads describe one config."""
    config = model_config(
        small_export.onnx, TritonOptions(kind="gpu", gpus=(0, 1), tensorrt=True, tensorrt_cache="/cache")
    )
    from_text = text_format.Parse(render_pbtxt(config), model_config_pb2.ModelConfig())
    assert from_text == json_format.ParseDict(config, model_config_pb2.ModelConfig())
    (accelerator,) = from_text.optimization.execution_accelerators.gpu_execution_accelerator
    assert accelerator.name == "tensorrt"
    assert dict(accelerator.parameters) == {
        "precision_mode": "FP16",
        "max_workspace_size_bytes": str(1 << 30),
        "trt_engine_cache_enable": "1",
        "trt_engine_cache_path": "/cache",
    }
    assert list(from_text.instance_group[0].gpus) == [0, 1]


def test_without_batching_the_batch_axis_is_in_the_dims(small_export) -> None:
    config = text_format.Parse(
        render_pbtxt(model_config(small_export.onnx, TritonOptions(max_batch_size=0))), model_config_pb2.ModelConfig()
    )
    assert config.max_batch_size == 0 and not config.HasField("dynamic_batching")
    assert list(config.input[0].dims) == [-1, 4, 160, 160, 3]


@pytest.mark.parametrize(
    "options, message",
    [
        ({"tensorrt": True}, "tensorrt: TensorRT runs on GPU instances"),  # TensorRT on CPU instances
        ({"max_batch_size": -1}, "max_batch_size"),
        ({"preferred_batch_sizes": (8,), "max_batch_size": 4}, "preferred_batch_sizes: [8]"),
        ({"instances": 0}, "instances"),
        ({"name": "../escape"}, "name: '../escape'"),  # a name that would leave the repository
        ({"gpus": (0,)}, "gpus: only for kind='gpu'"),
        ({"backend": "python", "kind": "gpu"}, "the python form runs ONNX Runtime on the CPU"),
        ({"backend": "tensorflow"}, "backend: expected onnxruntime or python"),
    ],
)
def test_bad_options_are_named(options: dict, message: str) -> None:
    with pytest.raises(ValueError, match=message.replace("[", r"\[").replace("]", r"\]")):
        TritonOptions(**options)


def test_existing_model_folder_is_kept_unless_forced(small_export, tmp_path: Path) -> None:
    target = write_repository(small_export.onnx, tmp_path, TritonOptions(name="m"))
    (target / "config.pbtxt").write_text("edited")
    with pytest.raises(ExportError, match="already exists"):
        write_repository(small_export.onnx, tmp_path, TritonOptions(name="m"))
    assert (target / "config.pbtxt").read_text() == "edited"
    write_repository(small_export.onnx, tmp_path, TritonOptions(name="m"), force=True)
    assert _parse(target / "config.pbtxt").name == "m"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m"]  # no staging folder left behind


def test_a_file_without_metadata_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ArtifactError, match="no such file"):
        model_config(tmp_path / "missing.onnx")
    (tmp_path / "junk.onnx").write_bytes(b"not onnx")
    with pytest.raises(ArtifactError, match="ONNX Runtime cannot load it"):
        model_config(tmp_path / "junk.onnx")


def test_command(small_export, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert (
        main(
            [
                "triton",
                str(small_export.onnx),
                "--out",
                str(tmp_path),
                "--name",
                "fisheye",
                "--instances",
                "2",
                "--kind",
                "cpu",
            ]
        )
        == 0
    )
    assert _parse(tmp_path / "fisheye" / "config.pbtxt").instance_group[0].count == 2
    assert "tritonserver --model-repository=/models" in capsys.readouterr().out
    assert main(["triton", str(small_export.onnx), "--out", str(tmp_path), "--tensorrt"]) == 1
    assert "tensorrt: TensorRT runs on GPU instances" in capsys.readouterr().err


def test_python_form_has_the_same_interface_and_runs_the_files_session(small_export, tmp_path: Path) -> None:
    """The Python-backend form: the ONNX Runtime form's inputs, outputs and batching; model.py beside the file."""
    ort_form = _parse(write_repository(small_export.onnx, tmp_path / "ort", TritonOptions(name="m")) / "config.pbtxt")
    target = write_repository(small_export.onnx, tmp_path / "py", TritonOptions(name="m", backend="python", threads=2))
    config = _parse(target / "config.pbtxt")
    assert config.backend == "python" and not config.default_model_filename
    assert (config.input, config.output, config.dynamic_batching) == (
        ort_form.input,
        ort_form.output,
        ort_form.dynamic_batching,
    )
    assert config.instance_group[0].kind == model_config_pb2.ModelInstanceGroup.KIND_CPU
    assert set(config.parameters) == {METADATA_KEY, "intra_op_thread_count"}  # no ORT-backend parameters
    assert (target / "1" / "model.py").read_text() == MODEL_PY
    namespace: dict = {}
    exec(compile(MODEL_PY, "model.py", "exec"), namespace)  # what Triton's stub does with the file
    assert namespace["TritonPythonModel"] is TritonPythonModel


def test_python_form_checks_each_requests_tensors() -> None:
    shapes = {"images": [-1, 4, 8, 8, 3], "camera_valid": [-1, 4]}
    good = {"images": np.zeros((2, 4, 8, 8, 3), np.uint8), "camera_valid": np.ones((2, 4), bool)}
    assert check_request(good, shapes) == 2
    cases = [
        ({"camera_valid": None}, "input 'camera_valid': missing"),
        ({"images": np.zeros((2, 4, 8, 8, 3), np.float32)}, "input 'images': expected uint8, got float32"),
        ({"images": np.zeros((2, 4, 8, 9, 3), np.uint8)}, r"input 'images': expected shape \[-1, 4, 8, 8, 3\]"),
        ({"camera_valid": np.ones((3, 4), bool)}, "inputs' batches differ"),
    ]
    for change, message in cases:
        with pytest.raises(FrameError, match=message):
            check_request({**good, **change}, shapes)
