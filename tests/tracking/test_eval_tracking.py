"""``fisheye-infer eval --tracking``: a detector and the tracker over written sequences, scored and saved."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from fisheye_infer.cameras.rig import default_rig
from fisheye_infer.cli import main
from fisheye_infer.scenes.render import resized_rig
from fisheye_infer.scenes.sequences import SyntheticSequences, write_sequences


def test_eval_tracking_reports_and_saves_tracks(small_export, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    data = tmp_path / "seqs"
    write_sequences(SyntheticSequences(resized_rig(default_rig(), 0.2), "val", 0, length=5), data, range(2))
    out, saved = tmp_path / "report.json", tmp_path / "tracks.json"
    args = ["eval", str(small_export.onnx), "--data", str(data), "--tracking", "--track-score", "0.05"]
    assert main([*args, "--out", str(out), "--save-results", str(saved)]) == 0
    report = json.loads(out.read_text())
    assert set(report) == {"0-30m", "0-48m"}
    assert {"amota", "amotp", "mota", "motp", "ids", "frag", "recall"} <= set(report["0-48m"]["overall"])
    assert report["0-48m"]["overall"]["gt"] > 0
    tracks = json.loads(saved.read_text())
    assert tracks["meta"]["use_tracking"] is True and len(tracks["results"]) == 10
    records = [r for rs in tracks["results"].values() for r in rs]
    assert all({"tracking_id", "tracking_name", "tracking_score", "velocity"} <= set(r) for r in records)
    gt = json.loads(saved.with_suffix(".gt.json").read_text())["results"]
    assert all("tracking_id" in r for rs in gt.values() for r in rs)
    assert "## Tracking, 0-30 m" in out.with_suffix(".md").read_text()
    dets = json.loads(saved.with_suffix(".detections.json").read_text())["results"]
    first = next(r for rs in dets.values() for r in rs)
    assert {"detection_name", "detection_score", "velocity", "translation"} <= set(first) and "tracking_id" not in first


def test_eval_tracking_needs_a_model(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["eval", "--tracking", "--out", str(tmp_path / "r.json")]) == 2
    assert "--tracking runs a MODEL on --data" in capsys.readouterr().err


def test_eval_tracking_adds_hota_when_asked(small_export, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    pytest.importorskip("trackeval.metrics")
    data = tmp_path / "seqs"
    write_sequences(SyntheticSequences(resized_rig(default_rig(), 0.2), "val", 0, length=4), data, range(1))
    out = tmp_path / "report.json"
    args = ["eval", str(small_export.onnx), "--data", str(data), "--tracking", "--track-score", "0.05", "--hota"]
    assert main([*args, "--out", str(out)]) == 0
    report = json.loads(out.read_text())
    assert set(report["0-48m"]["hota"]["overall"]) == {"hota", "deta", "assa", "loca"}
    assert "HOTA " in out.with_suffix(".md").read_text()


def test_eval_tracking_smooths_the_saved_velocities(small_export, tmp_path: Path) -> None:  # type: ignore[no-untyped-def]
    """``--smooth`` changes the saved velocities and nothing the metrics read."""
    data = tmp_path / "seqs"
    write_sequences(SyntheticSequences(resized_rig(default_rig(), 0.2), "val", 0, length=8), data, range(1))
    args = ["eval", str(small_export.onnx), "--data", str(data), "--tracking", "--track-score", "0.05"]
    saved = {}
    for smooth in ("0", "0.3"):
        out = tmp_path / f"report-{smooth}.json"
        assert (
            main([*args, "--smooth", smooth, "--out", str(out), "--save-results", str(tmp_path / f"{smooth}.json")])
            == 0
        )
        saved[smooth] = (out.read_text(), json.loads((tmp_path / f"{smooth}.json").read_text())["results"])
    assert saved["0"][0] == saved["0.3"][0]
    online = [r for rs in saved["0"][1].values() for r in rs]
    smoothed = [r for rs in saved["0.3"][1].values() for r in rs]
    assert [r["translation"] for r in online] == [r["translation"] for r in smoothed]
    assert [r["velocity"] for r in online] != [r["velocity"] for r in smoothed]


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--tracking", "--smooth", "-1"], "--smooth: expected seconds >= 0"),
        (["--smooth", "1"], "goes with --tracking"),
    ],
)
def test_eval_refuses_a_bad_smooth(  # type: ignore[no-untyped-def]
    small_export, tmp_path: Path, capsys: pytest.CaptureFixture[str], extra: list[str], message: str
) -> None:
    args = ["eval", str(small_export.onnx), "--data", str(tmp_path), *extra, "--out", str(tmp_path / "r.json")]
    assert main(args) == 2
    assert message in capsys.readouterr().err


def test_eval_refuses_smooth_on_saved_results(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    args = [
        "eval",
        "--results",
        "p.json",
        "--ground-truth",
        "g.json",
        "--smooth",
        "1",
        "--out",
        str(tmp_path / "r.json"),
    ]
    assert main(args) == 2
    assert "--smooth fits tracks' velocities; it goes with --tracking" in capsys.readouterr().err
