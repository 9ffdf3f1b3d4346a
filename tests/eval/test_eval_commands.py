"""``fisheye-infer eval`` and ``synth``: argparse in, files and exit codes out."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest
from eval_cases import SynthSet, one_of_each

from fisheye_infer.commands import eval as eval_command
from fisheye_infer.commands import synth as synth_command
from fisheye_infer.errors import FisheyeInferError
from fisheye_infer.eval.dataset import Fisheye3DOD
from fisheye_infer.eval.evaluate import evaluate_results, save_results
from fisheye_infer.eval.metrics import MetricsReport


def _run(configure, argv: list[str]) -> int:
    parser = argparse.ArgumentParser(prog="fisheye-infer")
    configure(parser)
    args = parser.parse_args(argv)
    return args.run(args)


def test_eval_saved_results_writes_json_and_markdown(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    gt, pred = {"s": one_of_each()}, {"s": one_of_each(score=0.8, shift=0.7)}
    save_results(tmp_path / "gt.json", gt)
    save_results(tmp_path / "pred.json", pred)
    out = tmp_path / "reports" / "report.json"
    assert (
        _run(
            eval_command.configure,
            ["--results", str(tmp_path / "pred.json"), "--ground-truth", str(tmp_path / "gt.json"), "--out", str(out)],
        )
        == 0
    )
    report = MetricsReport.from_json(out.read_text())
    assert report.details() == evaluate_results(gt, pred).details()
    assert out.with_suffix(".md").read_text() == report.to_markdown()
    printed = capsys.readouterr().out
    assert "| FDS | mAP | mATE | mASE | mAOE |" in printed and "0-30 m" in printed
    doc = json.loads(out.read_text())
    assert {"FDS", "mAP", "mATE", "mASE", "mAOE"} <= set(doc["main"]) and set(
        doc["main"]["classes"]["Car"]["ap_by_threshold"]
    ) == {"0.5", "1.0", "2.0", "4.0"}
    assert all(
        doc[k] == doc["main"][k] for k in ("FDS", "mAP", "mATE", "mASE", "mAOE")
    )  # headline figures at the top too


def test_eval_with_config_and_ref_range(tmp_path: Path) -> None:
    save_results(tmp_path / "gt.json", {"s": one_of_each()})
    save_results(tmp_path / "pred.json", {"s": one_of_each(score=0.9)})
    (tmp_path / "eval.json").write_text(json.dumps({"distance_breakdown": [20.0]}))
    argv = [
        "--results",
        str(tmp_path / "pred.json"),
        "--ground-truth",
        str(tmp_path / "gt.json"),
        "--config",
        str(tmp_path / "eval.json"),
        "--ref-range",
        "36",
    ]
    assert _run(eval_command.configure, [*argv, "--out", str(tmp_path / "r.json")]) == 0
    report = MetricsReport.from_json((tmp_path / "r.json").read_text())
    assert report.config.ref_range == 36 and list(report.distance) == ["0-20 m"]


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--results", "p.json"], "give --results and --ground-truth"),
        (["--results", "p.json", "--ground-truth", "g.json", "--data", "d"], "--data needs a MODEL"),
        (["model.onnx"], "a MODEL needs --data"),
        (["model.onnx", "--data", "d", "--results", "p.json"], "--results/--ground-truth are for saved results"),
    ],
)
def test_eval_refuses_mixed_or_missing_arguments(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(eval_command.configure, [*argv, "--out", str(tmp_path / "r.json")]) == 2
    assert message in capsys.readouterr().err


def test_eval_refuses_a_markdown_out_path(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """The Markdown report goes beside the JSON one; ``--out x.md`` would have it overwrite the JSON."""
    save_results(tmp_path / "gt.json", {"s": one_of_each()})
    save_results(tmp_path / "pred.json", {"s": one_of_each(score=0.9)})
    argv = [
        "--results",
        str(tmp_path / "pred.json"),
        "--ground-truth",
        str(tmp_path / "gt.json"),
        "--out",
        str(tmp_path / "r.md"),
    ]
    assert _run(eval_command.configure, argv) == 2
    assert "--out names the report JSON" in capsys.readouterr().err and not (tmp_path / "r.md").exists()


def test_eval_runs_an_exported_model_over_synthetic_data(
    small_export, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """The whole loop: a real ONNX model in ONNX Runtime over Fisheye3DOD-layout frames rendered for its
    rig, scored with FDS; then with two cameras only (degraded mode)."""
    from fisheye_infer.runtime.artifact import read_meta
    from fisheye_infer.scenes.render import synthesize

    rig = read_meta(small_export.onnx).rig
    synthesize(rig, tmp_path / "data", frames=2, seed=4)
    out = tmp_path / "report.json"
    assert (
        _run(
            eval_command.configure,
            [
                str(small_export.onnx),
                "--data",
                str(tmp_path / "data"),
                "--split",
                "val",
                "--out",
                str(out),
                "--save-results",
                str(tmp_path / "pred.json"),
            ],
        )
        == 0
    )
    assert "2/2 frames" in capsys.readouterr().err  # the progress bar's last line
    doc = json.loads(out.read_text())
    assert {"FDS", "mAP", "mATE", "mASE", "mAOE"} <= set(doc["main"])
    assert 0.0 <= doc["main"]["FDS"] <= 1.0
    saved = json.loads((tmp_path / "pred.json").read_text())["results"]
    assert len(saved) == 2 and all(isinstance(r, list) for r in saved.values())
    out2 = tmp_path / "front_rear.json"
    argv = [
        str(small_export.onnx),
        "--data",
        str(tmp_path / "data"),
        "--split",
        "val",
        "--cameras",
        "front,rear",
        "--out",
        str(out2),
        "--save-results",
        str(tmp_path / "pred2.json"),
    ]
    assert _run(eval_command.configure, argv) == 0
    assert {"FDS", "mAP"} <= set(json.loads(out2.read_text())["main"])
    degraded = json.loads((tmp_path / "pred2.json").read_text())["results"]
    assert degraded.keys() == saved.keys() and degraded != saved  # two cameras missing changed the detections


def test_eval_model_that_does_not_exist_is_a_clear_error(synth_set: SynthSet, tmp_path: Path) -> None:
    with pytest.raises(FisheyeInferError, match="no such file"):
        _run(
            eval_command.configure,
            [str(tmp_path / "missing.onnx"), "--data", str(synth_set.root), "--out", str(tmp_path / "r.json")],
        )


def test_synth_then_evaluate_its_ground_truth(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    root = tmp_path / "synth"
    assert (
        _run(
            synth_command.configure,
            ["--frames", "2", "--out", str(root), "--seed", "3", "--scale", "0.1", "--objects", "4,6"],
        )
        == 0
    )
    assert "next: fisheye-infer eval MODEL --data" in capsys.readouterr().out
    data = Fisheye3DOD(root, "val")
    assert len(data) == 2 and data[0].image("front").shape == (80, 80, 3)
    gt = data.ground_truth()
    pred = {token: [{**r, "detection_score": 0.5} for r in records] for token, records in gt.items()}
    save_results(tmp_path / "gt.json", gt)
    save_results(tmp_path / "pred.json", pred)
    assert (
        _run(
            eval_command.configure,
            [
                "--results",
                str(tmp_path / "pred.json"),
                "--ground-truth",
                str(tmp_path / "gt.json"),
                "--out",
                str(tmp_path / "r.json"),
            ],
        )
        == 0
    )
    report = MetricsReport.from_json((tmp_path / "r.json").read_text())
    present = [c for c in report.main.classes.values() if c.trans_err == 0.0]
    assert present and all(c.ap == pytest.approx(1.0) for c in present)


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--frames", "0"], "--frames must be at least 1"),
    ],
)
def test_synth_refuses_bad_counts(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(synth_command.configure, [*argv, "--out", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err


def test_synth_objects_argument_is_checked() -> None:
    parser = argparse.ArgumentParser()
    synth_command.configure(parser)
    with pytest.raises(SystemExit):
        parser.parse_args(["--out", "x", "--objects", "9,3"])


def test_synth_stream_writes_the_training_commands_validation_frames(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import cv2
    import numpy as np

    from fisheye_infer.cameras.rig import default_rig
    from fisheye_infer.runtime.records import records_to_arrays
    from fisheye_infer.scenes.render import resized_rig
    from fisheye_infer.scenes.streams import SyntheticFrames

    rig = resized_rig(default_rig(), 0.1)
    rig.save(tmp_path / "rig.json")
    root = tmp_path / "heldout"
    assert (
        _run(
            synth_command.configure,
            [
                "--stream",
                "val",
                "--rig",
                str(tmp_path / "rig.json"),
                "--first",
                "5",
                "--frames",
                "2",
                "--out",
                str(root),
            ],
        )
        == 0
    )
    assert "--split val" in capsys.readouterr().out
    data, stream = Fisheye3DOD(root, "val"), SyntheticFrames(rig, "val")
    assert [f.token.rsplit(".", 1)[1] for f in data] == ["00000005", "00000006"]
    for frame, index in zip(data, (5, 6)):
        sample = stream[index]
        for camera, image in zip(rig.names, sample.images):
            np.testing.assert_array_equal(cv2.imread(str(dict(frame.image_paths)[camera])), image)
        boxes, _, labels = records_to_arrays(frame.gt_records())
        np.testing.assert_allclose(boxes, sample.boxes, atol=1e-9)
        np.testing.assert_array_equal(labels, sample.labels)
        assert np.abs(frame.rig.cam2lidar() - rig.cam2lidar()).max() < 1e-12


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--stream", "val", "--objects", "2,3"], "--objects belong(s) to the plain scenes"),
        (["--stream", "val", "--first", "-1"], "--first must be at least 0"),
        (["--first", "3"], "--first needs --stream"),
    ],
)
def test_synth_stream_options_are_checked(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert _run(synth_command.configure, [*argv, "--scale", "0.1", "--out", str(tmp_path)]) == 2
    assert message in capsys.readouterr().err
