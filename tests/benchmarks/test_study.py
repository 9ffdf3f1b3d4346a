"""benchmarks/study.py: which rows and findings a set of studied models gives, on reports the metric computes, and
how sure the held-out scenes make each finding."""

from __future__ import annotations

import sys
from functools import cache
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT / "tests" / "eval"))

import study
from eval_cases import one_of_each

from fisheye_infer.cameras.rig import FISHEYE3DOD_CAMERAS, PINHOLE_CAMERAS
from fisheye_infer.eval.metrics import MetricsReport

FRONT, LEFT, RIGHT, REAR = FISHEYE3DOD_CAMERAS


def scored(*shifts: float) -> study.Scored:
    """Predictions ``shifts[i]`` metres off every object of frame i: the larger, the lower the FDS."""
    gt = {f"frame{i}": one_of_each() for i in range(len(shifts))}
    pred = {token: one_of_each(score=0.9, shift=shift) for token, shift in zip(gt, shifts)}
    return study.Scored.of(gt, pred)


@cache
def even(shift: float) -> study.Scored:
    """Two frames, both ``shift`` metres off: every resample of the frames scores the same."""
    return scored(shift, shift)


def report(shift: float) -> MetricsReport:
    return even(shift).report


def model(name: str, arch: str, shift: float, layout: str = study.ALL, **runtime: float) -> study.Studied:
    labels = {"front_rear": "front + rear", "left_right": "left + right", "no_front_rear": "without front and rear"}
    layouts = {labels[k]: even(v) for k, v in runtime.items()}
    return study.Studied(name, arch, layout, even(shift), layouts)


def test_reports_rank_by_shift() -> None:
    fds = [report(shift).distance[study.FAR].FDS for shift in (0.0, 0.3, 0.8, 1.5)]
    assert fds == sorted(fds, reverse=True) and len(set(fds)) == 4


@pytest.mark.parametrize(
    ("arch", "cameras", "layout"),
    [
        ("fisheye-bevdet", FISHEYE3DOD_CAMERAS, study.ALL),
        ("fisheye-bevdet", (FRONT, REAR), "front + rear"),
        ("fisheye-petr", (RIGHT, LEFT), "left + right"),
        ("fisheye-bevdet", (FRONT,), FRONT),
        ("pinhole-bevdet", PINHOLE_CAMERAS, study.ALL),
        (
            "pinhole-bevdet",
            tuple(c for c in PINHOLE_CAMERAS if not c.endswith(("front", "rear"))),
            "without front and rear",
        ),
        ("fisheye-bevdet", ("cam_a", "cam_b"), study.ALL),  # a user's own rig is a whole rig
        ("fisheye-bevdet", ("cam_a", "cam_b", "cam_c", "cam_d"), study.ALL),
        ("fisheye-petr", ("cam_rear", "cam_front"), "front + rear"),  # unless named as a paper's layout
        ("fisheye-bevdet-cyl", ("Left", "Right"), "left + right"),
        ("fisheye-bevdet", ("cam_front", "cam_left"), study.ALL),
    ],
)
def test_trained_layout_names_the_papers_reduced_layouts(arch: str, cameras: tuple[str, ...], layout: str) -> None:
    assert study.trained_layout(arch, cameras) == layout


@pytest.mark.parametrize(
    ("cameras", "layouts"),
    [
        (FISHEYE3DOD_CAMERAS, {"front + rear": [FRONT, REAR], "left + right": [LEFT, RIGHT]}),
        (("a_front", "b_left", "c_right", "d_back"), {"left + right": ["b_left", "c_right"]}),
        (("a", "b", "c", "d"), {}),
        (PINHOLE_CAMERAS, {"without front and rear": [c for c in PINHOLE_CAMERAS if c.endswith(("left", "right"))]}),
    ],
)
def test_the_papers_layouts_are_found_by_camera_names(cameras: tuple[str, ...], layouts: dict) -> None:
    """Run-time layouts of a rig: a pair only where two cameras' names end in its words."""
    assert study.paper_layouts(cameras) == layouts


def test_retrained_layouts_are_rows_of_table_3_only() -> None:
    models = [
        model("fb", "fisheye-bevdet", 0.3, front_rear=0.8, left_right=1.5),
        model("fb-fr", "fisheye-bevdet", 0.5, layout="front + rear"),
    ]
    assert [r["model"] for r in study.table2(models)] == ["fb"]
    assert [r["model"] for r in study.table4(models)] == ["fb", "fb"]
    rows = [(r["model"], r["cameras"], r["reduced"], r["paper FDS"]) for r in study.table3(models)]
    assert rows == [
        ("fb", "front + rear", study.RUN_TIME, 0.454),
        ("fb", "left + right", study.RUN_TIME, 0.431),
        ("fb", "all", "-", 0.485),
        ("fb-fr", "front + rear", study.RETRAINED, 0.454),
    ]


def _findings(models: list[study.Studied]) -> dict[str, tuple[str | None, str, str | None]]:
    return {
        r["comparison (FDS, 0-48 m)"]: (r["paper"], r["ours"], r["same direction"])
        for r in study.findings(models, draws=20)
    }


def test_findings_compare_the_models_studied_together() -> None:
    fds = {shift: f"{report(shift).distance[study.FAR].FDS:.3f}" for shift in (0.0, 0.3, 0.8, 1.5)}
    found = _findings(
        [
            model("fb", "fisheye-bevdet", 0.3),
            model("pinhole", "pinhole-bevdet", 0.0),
            model("persp", "fisheye-bevdet-persp", 0.8),
        ]
    )
    near = report(0.3).distance[study.NEAR].FDS
    # every object lies within 30 m: the two ranges score alike on every resample
    assert near == report(0.3).distance[study.FAR].FDS
    assert found == {
        "BEVDet 6 x P vs BEVDet 4 x F, perspective-rectified": ("0.563 vs 0.440", f"{fds[0.0]} vs {fds[0.8]}", "yes"),
        "FisheyeBEVDet vs BEVDet 4 x F, perspective-rectified": ("0.485 vs 0.440", f"{fds[0.3]} vs {fds[0.8]}", "yes"),
        "FisheyeBEVDet vs BEVDet 6 x P": ("0.485 vs 0.563", f"{fds[0.3]} vs {fds[0.0]}", "yes"),
        "FisheyeBEVDet: 0-30 m vs 0-48 m": ("0.586 vs 0.485", f"{near:.3f} vs {fds[0.3]}", "not resolved"),
    }


def test_findings_of_reduced_layouts_at_run_time_and_retrained() -> None:
    models = [
        model("fb", "fisheye-bevdet", 0.0, front_rear=1.5, left_right=0.8),
        model("pinhole", "pinhole-bevdet", 0.0, no_front_rear=0.3),
        model("fb-fr", "fisheye-bevdet", 0.3, layout="front + rear"),
        model("fb-lr", "fisheye-bevdet", 0.8, layout="left + right"),
        model("pinhole-4", "pinhole-bevdet", 1.5, layout="without front and rear"),
    ]
    found = _findings(models)
    fds = {shift: report(shift).distance[study.FAR].FDS for shift in (0.0, 0.3, 0.8, 1.5)}
    # the paper: front + rear above left + right; here at run time the other way, retrained the same way
    assert found["FisheyeBEVDet: front + rear vs left + right, run time"][2] == "no"
    assert found["FisheyeBEVDet: front + rear vs left + right, retrained"][2] == "yes"
    # RF1: the FDS lost without front and rear, pinhole against fisheye (the paper: 0.193 against 0.054)
    lost = "FDS lost without front and rear: BEVDet 6 x P vs FisheyeBEVDet left + right"
    assert found[f"{lost}, run time"] == (
        "0.193 vs 0.054",
        f"{fds[0.0] - fds[0.3]:.3f} vs {fds[0.0] - fds[0.8]:.3f}",
        "no",
    )
    assert found[f"{lost}, retrained"] == (
        "0.193 vs 0.054",
        f"{fds[0.0] - fds[1.5]:.3f} vs {fds[0.0] - fds[0.8]:.3f}",
        "yes",
    )


def test_two_models_of_one_architecture_and_layout_are_refused() -> None:
    study.comparable([model("a", "fisheye-bevdet", 0.0), model("b", "fisheye-bevdet", 0.0, layout="front + rear")])
    with pytest.raises(SystemExit, match="--model a and --model b are both fisheye-bevdet trained with all cameras"):
        study.comparable([model("a", "fisheye-bevdet", 0.0), model("b", "fisheye-bevdet", 0.3)])


def test_models_scored_on_other_scenes_are_refused() -> None:
    three = study.Studied("c", "pinhole-bevdet", study.ALL, scored(0.0, 0.0, 0.0), {})
    with pytest.raises(SystemExit, match="--model a and --model c were scored on different scenes \\(2 and 3 frames"):
        study.comparable([model("a", "fisheye-bevdet", 0.0), three])


def _row(models: list[study.Studied], comparison: str) -> dict:
    return next(r for r in study.findings(models, draws=50) if r["comparison (FDS, 0-48 m)"] == comparison)


def test_a_difference_every_scene_agrees_on_is_resolved() -> None:
    """Every frame of the fisheye model is better: every resample keeps the sign, the interval is the difference."""
    fisheye, pinhole = model("fb", "fisheye-bevdet", 0.0), model("pinhole", "pinhole-bevdet", 0.8)
    row = _row([fisheye, pinhole], "FisheyeBEVDet vs BEVDet 6 x P")
    difference = report(0.0).distance[study.FAR].FDS - report(0.8).distance[study.FAR].FDS
    assert difference > 0
    assert row["ours, difference (90% interval)"] == f"{difference:+.3f} ({difference:+.3f} to {difference:+.3f})"
    assert row["same direction"] == "no"  # the paper: pinhole above FisheyeBEVDet


def test_a_difference_the_scenes_split_on_is_not_resolved() -> None:
    """One model far better on half the scenes, the other on the other half: resamples take either side."""
    shifts = (0.0, 0.0, 0.0, 1.5, 1.5, 1.5)
    fisheye = study.Studied("fb", "fisheye-bevdet", study.ALL, scored(*shifts), {})
    pinhole = study.Studied("pinhole", "pinhole-bevdet", study.ALL, scored(*shifts[::-1]), {})
    row = _row([fisheye, pinhole], "FisheyeBEVDet vs BEVDet 6 x P")
    low, high = (float(v) for v in row["ours, difference (90% interval)"].split("(")[1].rstrip(")").split(" to "))
    assert low < 0 < high
    assert row["same direction"] == "not resolved"


def test_no_resamples_is_refused_before_any_work(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        study.main(["--draws", "0", "--frames", "1"])
    assert "--draws: expected at least 1 resample, got 0" in capsys.readouterr().err


def test_a_run_folder_names_its_checkpoint(tmp_path: Path) -> None:
    run = tmp_path / "mine-cyl"
    run.mkdir()
    for name in ("model.pth", "config.py", "rig.json"):
        (run / name).write_bytes(b"")
    assert study.model_files(str(run)) == ("mine-cyl", run / "model.pth", run / "config.py", run / "rig.json")
    assert study.model_files(str(run / "model.pth")) == study.model_files(str(run))


def test_a_checkpoint_without_its_run_files_is_refused_before_any_work(tmp_path: Path) -> None:
    (tmp_path / "model.pth").write_bytes(b"")
    (tmp_path / "config.py").write_text("")
    work = tmp_path / "work"
    argv = ["--model", "fisheye-bevdet-compact", "--model", str(tmp_path / "model.pth"), "--work-dir", str(work)]
    with pytest.raises(SystemExit, match=r"no rig.json beside model.pth"):
        study.main([*argv, "--frames", "1"])
    assert not work.exists()  # the first model was neither rendered for nor exported
    with pytest.raises(SystemExit, match="neither a shipped model"):
        study.model_files(str(tmp_path / "elsewhere"))
