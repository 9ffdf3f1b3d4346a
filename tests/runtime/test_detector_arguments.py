"""Every ``Detector`` constructor argument checked before any work, refused with the project's own error naming
the argument and what was expected: in-process, on the reduced export in real ONNX Runtime."""

from __future__ import annotations

import json
import os
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from fisheye_infer.errors import ArtifactError, ConfigError, FisheyeInferError, OptionError
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.runtime.session import THREADS_PER_CPU, usable_cpus

MOST = THREADS_PER_CPU * usable_cpus()
THREADS_RANGE = rf"expected a whole number from 1 to {MOST} \({THREADS_PER_CPU} x the {usable_cpus()} CPU\(s\)"


@pytest.mark.parametrize(
    "options, error, message",
    [
        ({"threads": 0}, OptionError, rf"threads: {THREADS_RANGE}.*got int 0"),
        ({"threads": -1}, OptionError, rf"threads: {THREADS_RANGE}.*got int -1"),
        ({"threads": MOST + 1}, OptionError, rf"threads: {THREADS_RANGE}.*got int {MOST + 1}"),
        ({"threads": 10_000}, OptionError, "got int 10000"),  # construction had not ended after 240 s
        ({"threads": 1.5}, OptionError, "threads: .* got float 1.5"),  # accepted silently before
        ({"threads": 2.0}, OptionError, "threads: .* got float 2.0"),
        ({"threads": "2"}, OptionError, "threads: .* got str '2'"),
        ({"threads": True}, OptionError, "threads: .* got bool True"),
        ({"decode_threads": 0}, OptionError, "decode_threads: .* got int 0"),
        ({"decode_threads": "4"}, OptionError, "decode_threads: .* got str '4'"),
        ({"providers": 5}, ConfigError, "providers: expected 'auto', a provider name or a list of them.* got int"),
        ({"providers": {"CPUExecutionProvider": {}}}, ConfigError, "providers: expected .* got dict"),
        ({"providers": b"CPUExecutionProvider"}, ConfigError, "providers: expected .* got bytes"),
        ({"providers": [5]}, ConfigError, "providers: expected a provider name or a .* pair, got 5"),
        ({"providers": ["NoSuchExecutionProvider"]}, ConfigError, "NoSuchExecutionProvider not offered"),
        ({"warmup": "no"}, OptionError, "warmup: expected True or False, got str 'no'"),
        ({"spin": 0}, OptionError, "spin: expected True or False, got int 0"),
    ],
)
def test_constructor_arguments_are_refused_by_name(
    small_export, options: dict[str, Any], error: type[Exception], message: str
) -> None:
    with pytest.raises(error, match=message) as raised:
        Detector(small_export.onnx, **{"warmup": False, **options})
    assert isinstance(raised.value, FisheyeInferError)


@pytest.mark.parametrize(
    "path, error, message",
    [
        (None, OptionError, r"model_path: expected the path of an ONNX file \(str or os.PathLike\), got NoneType"),
        (3, OptionError, "model_path: .* got int"),
        (b"model.onnx", OptionError, "model_path: .* got bytes"),
        ("no/such/model.onnx", ArtifactError, "model no/such/model.onnx: no such file"),
        ("bad\0name.onnx", ArtifactError, "no such file"),
        ("x" * 5000 + ".onnx", OptionError, "model_path: .* cannot name a file"),
    ],
)
def test_the_model_path_must_name_a_file(path: object, error: type[Exception], message: str) -> None:
    with pytest.raises(error, match=message):
        Detector(path)  # type: ignore[arg-type]


def test_a_folder_is_not_a_model(tmp_path: Path) -> None:
    with pytest.raises(ArtifactError, match="is a folder or device, not an ONNX file"):
        Detector(tmp_path)


def test_threads_at_the_bound_and_numpy_integers_are_taken(small_export) -> None:
    detector = Detector(small_export.onnx, threads=np.int64(1), decode_threads=MOST, warmup=False)
    assert detector._session.get_session_options().intra_op_num_threads == 1
    assert Detector(os.fspath(small_export.onnx), threads=1, providers="CPUExecutionProvider", warmup=False)


@pytest.mark.parametrize(
    "document, words",
    [
        ("[" * 100_000 + "]" * 100_000, "'fisheye_infer' metadata is not JSON (maximum recursion depth"),
        (json.dumps({"schema_version": "x" * 100_000}), "metadata schema_version 'xxxxxxxx"),
    ],
)
def test_hostile_metadata_in_a_model_file_is_an_artifact_error(
    small_export, tmp_path: Path, document: str, words: str
) -> None:
    """Metadata nested 100,000 deep was a RecursionError; a long schema version is not repeated whole."""
    onnx = pytest.importorskip("onnx")
    model = onnx.load(str(small_export.onnx))
    for prop in model.metadata_props:
        if prop.key == "fisheye_infer":
            prop.value = document
    onnx.save(model, str(tmp_path / "hostile.onnx"))
    with pytest.raises(ArtifactError, match=re.escape(words)) as raised:
        Detector(tmp_path / "hostile.onnx", threads=1, warmup=False)
    assert len(str(raised.value)) < 600
