"""The command line, run as a user runs it."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import cv2
import pytest

from fisheye_infer.cameras.rig import Rig
from fisheye_infer.cli import main


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
    result = subprocess.run(
        [sys.executable, "-m", "fisheye_infer", "rig", "show", str(bad)], capture_output=True, text=True, timeout=60
    )
    assert result.returncode == 1
    assert "error: rig file" in result.stderr and "Traceback" not in result.stderr


def test_output_into_a_closed_pipe_stops_quietly() -> None:
    """``fisheye-infer rig show | head -1`` with the reader gone before the first line: exit 141, no traceback."""
    process = subprocess.Popen(
        [sys.executable, "-m", "fisheye_infer", "rig", "show"], stdout=subprocess.PIPE, stderr=subprocess.PIPE
    )
    assert process.stdout is not None and process.stderr is not None
    process.stdout.close()  # before the interpreter has even started: every write meets a closed pipe
    stderr = process.stderr.read().decode()
    assert process.wait(timeout=120) == 141 and stderr == ""


@pytest.mark.slow  # whole exports: make test-fast leaves it out
def test_demo_runs_on_defaults(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["demo", "--out", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "554,668 of 960,000 frustum points" in out
    assert (tmp_path / "rig.png").is_file() and (tmp_path / "sampling_grid.png").is_file()
    # Each shipped model on the held-out frame's 11 objects, boxes from its own threshold: the compact
    # FisheyeBEVDet finds 8 with 2 other boxes (score >= 0.15), the compact FisheyePETR 8 with 2 (>= 0.4)
    for name, at_least, at_most_extra in (("fisheye-bevdet-compact", 5, 4), ("fisheye-petr-compact", 5, 4)):
        pattern = rf"{name} on the held-out frame: (\d+) of (\d+) labelled objects found .*?; (\d+) box\(es\) on no"
        found, total, extra = (int(v) for v in re.search(pattern, out).groups())
        assert total == 11 and found >= at_least and extra <= at_most_extra, (name, found, extra)
        assert (tmp_path / f"{name}.png").is_file() and (tmp_path / f"{name}.json").is_file()


def test_detect_writes_results_and_picture_then_redraws_them(small_export, tmp_path: Path) -> None:
    import json

    import numpy as np

    from fisheye_infer.runtime.artifact import read_meta
    from fisheye_infer.scenes.render import Renderer, random_scene

    rig = read_meta(small_export.onnx).rig
    frame_dir = tmp_path / "frame"
    frame_dir.mkdir()
    for name, image in Renderer().render(rig, random_scene(np.random.default_rng(1))).items():
        cv2.imwrite(str(frame_dir / f"{name.removeprefix('fisheye_camera_')}.png"), image)
    out, viz = tmp_path / "result.json", tmp_path / "result.png"
    assert (
        main(
            [
                "detect",
                str(small_export.onnx),
                "--images",
                str(frame_dir),
                "--out",
                str(out),
                "--viz",
                str(viz),
                "--score-threshold",
                "0.05",
                "--providers",
                "CPUExecutionProvider",
            ]
        )
        == 0
    )
    doc = json.loads(out.read_text())
    assert doc["model_id"] == read_meta(small_export.onnx).model_id and len(doc["frames"]) == 1
    frame = doc["frames"][0]
    assert all(d["score"] >= 0.05 for d in frame["detections"]) and len(frame["records"]) == len(frame["detections"])
    picture = cv2.imread(str(viz))
    assert picture is not None and picture.shape[1] > picture.shape[0]
    redrawn = tmp_path / "redrawn.png"
    assert main(["detect", "--result", str(out), "--images", str(frame_dir), "--viz", str(redrawn)]) == 0
    np.testing.assert_array_equal(cv2.imread(str(redrawn)), picture)


def test_detect_names_what_a_saved_result_lacks(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "other.json"
    bad.write_text('{"results": {}}')
    assert main(["detect", "--result", str(bad), "--viz", str(tmp_path / "x.png")]) == 1
    assert (
        "missing rig, classes, frames; expected a file written by 'fisheye-infer detect --out'"
        in capsys.readouterr().err
    )
    assert not (tmp_path / "x.png").exists()


def test_detect_without_images_is_a_clear_error(small_export, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["detect", str(small_export.onnx)]) == 1
    assert "give a model and --images" in capsys.readouterr().err


def test_detect_names_an_unknown_class(small_export, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    import numpy as np

    from fisheye_infer.runtime.artifact import read_meta
    from fisheye_infer.scenes.render import Renderer, random_scene

    frame_dir = tmp_path / "frame"
    frame_dir.mkdir()
    for name, image in (
        Renderer().render(read_meta(small_export.onnx).rig, random_scene(np.random.default_rng(1))).items()
    ):
        cv2.imwrite(str(frame_dir / f"{name}.png"), image)
    assert main(["detect", str(small_export.onnx), "--images", str(frame_dir), "--classes", "Car,Tram"]) == 1
    assert "--classes: unknown ['Tram']; the model's classes are Car" in capsys.readouterr().err
