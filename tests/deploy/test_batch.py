"""Ray Data batch inference on synthetic Fisheye3DOD frames: the plain loop's records, failures named, one results file."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.cli import main
from fisheye_infer.deploy.ray_batch import BatchOptions, dataset_frames, detect_frames
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.eval.evaluate import load_results, save_results
from fisheye_infer.runtime.detector import Detector
from fisheye_infer.scenes.render import resized_rig, synthesize


@pytest.fixture(scope="module")
def synth_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Five 160x160 frames for the reduced model's rig, with labels."""
    root = tmp_path_factory.mktemp("synth")
    synthesize(resized_rig(default_rig(), 0.2), root, frames=5, seed=4)
    return root


def _same_records(got: list[dict], want: list[dict]) -> None:
    assert [r["detection_name"] for r in got] == [r["detection_name"] for r in want]
    for key in ("translation", "size", "rotation"):
        np.testing.assert_allclose([r[key] for r in got], [r[key] for r in want], atol=1e-5)
    np.testing.assert_allclose([r["detection_score"] for r in got], [r["detection_score"] for r in want], atol=1e-6)


def test_ray_data_equals_a_plain_loop_and_names_the_failed_frame(
    ray_local, small_export, synth_root: Path, tmp_path: Path
) -> None:
    dataset = Fisheye3DOD(synth_root, "val")
    frames = dataset_frames(dataset)
    bad_token = frames[2][0]
    junk = tmp_path / "junk.png"
    junk.write_bytes(b"\x89PNG\r\n\x1a\n" + b"\0" * 40)  # a PNG signature and nothing usable
    frames[2] = (bad_token, {**frames[2][1], "fisheye_camera_front": junk})
    seen: list[int] = []
    result = detect_frames(
        small_export.onnx,
        frames,
        BatchOptions(batch_size=2, concurrency=2),
        progress=lambda done, total: seen.append(done),
    )
    assert list(result.failed) == [bad_token]
    assert "camera 'fisheye_camera_front'" in result.failed[bad_token]
    assert list(result.results) == [t for t, _ in frames if t != bad_token]  # input order, nothing skipped silently
    assert seen == [1, 2, 3, 4, 5]
    detector = Detector(small_export.onnx, threads=1)
    for token, files in frames:
        if token != bad_token:
            _same_records(result.results[token], detector.detect(files).to_nuscenes())
    assert sum(len(r) for r in result.results.values()) > 0


def test_detect_ray_writes_one_results_file_that_eval_reads(
    ray_local, small_export, synth_root: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    pred = tmp_path / "pred.json"
    assert (
        main(
            [
                "detect",
                str(small_export.onnx),
                "--ray",
                "--data",
                str(synth_root),
                "--out",
                str(pred),
                "--batch-size",
                "3",
            ]
        )
        == 0
    )
    err = capsys.readouterr().err
    assert "5/5 frames" in err  # progress shown
    doc = json.loads(pred.read_text())
    assert (
        doc["meta"]["failed"] == {}
        and doc["meta"]["model_id"] == Detector(small_export.onnx, warmup=False).info.model_id
    )
    assert list(load_results(pred)) == Fisheye3DOD(synth_root, "val").tokens
    gt = save_results(tmp_path / "gt.json", Fisheye3DOD(synth_root, "val").ground_truth())
    report = tmp_path / "report.json"
    assert main(["eval", "--results", str(pred), "--ground-truth", str(gt), "--out", str(report)]) == 0
    assert "mAP" in json.loads(report.read_text())


@pytest.mark.parametrize(
    "extra, message",
    [
        (["--viz", "x.png"], "--viz cannot be combined"),  # pictures need the plain command
        (
            ["--score-threshold", "0.3"],
            "--score-threshold cannot be combined",
        ),  # evaluation wants the unthresholded output
        (["--batch-size", "0"], "batch_size: expected at least 1"),
        (["--concurrency", "0"], "concurrency: expected at least 1"),
        (
            ["--providers", "CPUExecutionProvider"],
            "--providers: the --ray actors run on CPU",
        ),  # Ray reserves no GPU for them
    ],
)
def test_detect_ray_refuses_bad_options_before_starting_ray(
    small_export, synth_root: Path, tmp_path: Path, extra: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    argv = [
        "detect",
        str(small_export.onnx),
        "--ray",
        "--data",
        str(synth_root),
        "--out",
        str(tmp_path / "p.json"),
        *extra,
    ]
    assert main(argv) == 1
    assert message in capsys.readouterr().err


def test_duplicate_tokens_are_refused(small_export, synth_root: Path) -> None:
    frames = dataset_frames(Fisheye3DOD(synth_root, "val"))
    with pytest.raises(ValueError, match="appears twice"):
        detect_frames(small_export.onnx, [frames[0], frames[0]])


def test_detect_ray_over_a_folder_of_camera_folders(ray_local, small_export, synth_root: Path, tmp_path: Path) -> None:
    """--images DIR with one sub-folder per camera: frames named by their file stems, the same records as --data."""
    dataset = Fisheye3DOD(synth_root, "val")
    folder = dataset.image_paths(0)[
        "fisheye_camera_front"
    ].parent.parent  # <scene>/<vehicle>/ holds one folder per sensor
    pred = tmp_path / "pred.json"
    assert main(["detect", str(small_export.onnx), "--ray", "--images", str(folder), "--out", str(pred)]) == 0
    results = load_results(pred)
    assert list(results) == [e.frame_id for e in dataset.entries]
    detector = Detector(small_export.onnx, threads=1)
    _same_records(results[dataset.entries[0].frame_id], detector.detect(dataset.image_paths(0)).to_nuscenes())
