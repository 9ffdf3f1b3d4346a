"""The command line, run as a user runs it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from fisheye_infer.cli import main
from fisheye_infer.rig import Rig


def test_rig_show_prints_cameras_and_hash(rig: Rig, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["rig", "show"]) == 0
    out = capsys.readouterr().out
    assert rig.hash in out and all(name in out for name in rig.names)


def test_rig_plot_and_grid_write_pictures(tmp_path: Path) -> None:
    assert main(["rig", "plot", "--out", str(tmp_path / "rig.png")]) == 0
    assert main(["rig", "grid", "--camera", "fisheye_camera_left", "--out", str(tmp_path / "grid.png")]) == 0
    for name, shape in (("rig.png", (800, 800, 3)), ("grid.png", (800, 800, 3))):
        image = cv2.imread(str(tmp_path / name))
        assert image is not None and image.shape == shape and image.std() > 5


def test_rig_convert_then_show(tmp_path: Path, data_dir: Path, rig: Rig) -> None:
    folder = tmp_path / "rig"
    folder.mkdir()
    rig.save(tmp_path / "default.json")
    out = tmp_path / "rig.yaml"
    extrinsics = tmp_path / "lidar2cam.json"
    import json

    import numpy as np

    extrinsics.write_text(json.dumps({"cameras": {c.name: np.linalg.inv(c.matrix).tolist() for c in rig.cameras}}))
    calib = tmp_path / "calib_results.txt"
    calib.write_text(rig.shared_model().to_text())
    assert main(["rig", "convert", "--calib", str(calib), "--extrinsics", str(extrinsics), "--out", str(out)]) == 0
    assert Rig.load(out).names == rig.names


def test_bad_rig_is_a_clear_error_not_a_traceback(tmp_path: Path) -> None:
    bad = tmp_path / "rig.json"
    bad.write_text('{"cameras": []}')
    result = subprocess.run([sys.executable, "-m", "fisheye_infer", "rig", "show", str(bad)], capture_output=True, text=True)
    assert result.returncode == 1
    assert "error: rig file" in result.stderr and "Traceback" not in result.stderr


def test_demo_runs_on_defaults(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "554,668 of 960,000 frustum points" in out
    assert (tmp_path / "rig.png").is_file() and (tmp_path / "sampling_grid.png").is_file()
