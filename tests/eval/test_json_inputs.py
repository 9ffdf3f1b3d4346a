"""JSON files and texts read from outside (a split, labels, an eval config, saved detections, a saved detect
result): bytes that are not UTF-8, JSON nested 100,000 deep and a number of 5000 digits are each refused with
the project's own error naming the file, not a UnicodeDecodeError, RecursionError or ValueError traceback."""

from __future__ import annotations

from pathlib import Path

import pytest

from fisheye_infer.cli import main
from fisheye_infer.errors import ConfigError, DatasetError, FrameError
from fisheye_infer.eval.dataset import IMAGESETS, read_labels, read_split
from fisheye_infer.eval.metrics import EvalConfig
from fisheye_infer.runtime.detections import Detections

HOSTILE = {
    "binary": b"\xff\xfe\x00\x01binary",
    "deep": b"[" * 100_000 + b"]" * 100_000,
    "digits": b'{"results": ' + b"7" * 5000 + b"}",
}


@pytest.mark.parametrize("kind", sorted(HOSTILE))
def test_hostile_json_files_are_named_refusals(tmp_path: Path, kind: str, capsys) -> None:
    data = HOSTILE[kind]
    (tmp_path / IMAGESETS).mkdir()
    (tmp_path / IMAGESETS / "val.json").write_bytes(data)
    with pytest.raises(DatasetError, match="split 'val': .*val.json cannot be read as JSON"):
        read_split(tmp_path, "val")
    labels = tmp_path / "labels.json"
    labels.write_bytes(data)
    with pytest.raises(DatasetError, match="labels .*labels.json: cannot be read as JSON"):
        read_labels(labels)
    config = tmp_path / "eval.json"
    config.write_bytes(data)
    with pytest.raises(ConfigError, match="eval config .*eval.json: not"):
        EvalConfig.load(config)
    if kind != "binary":  # texts, already decoded
        with pytest.raises(FrameError, match="detections: not valid JSON"):
            Detections.from_json(data.decode(), ["Car"])
    result = tmp_path / "result.json"
    result.write_bytes(data)
    assert main(["detect", "--result", str(result), "--images", str(tmp_path), "--viz", str(tmp_path / "v.png")]) == 1
    assert f"--result {result}: cannot be read as JSON" in capsys.readouterr().err
