"""benchmarks/study.py: which rows and findings a set of studied models gives, on reports the metric computes."""

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
from fisheye_infer.eval.evaluate import evaluate_results
from fisheye_infer.eval.metrics import MetricsReport

FRONT, LEFT, RIGHT, REAR = FISHEYE3DOD_CAMERAS


@cache
def report(shift: float) -> MetricsReport:
    """The metric's report of predictions ``shift`` metres off every object: the larger, the lower the FDS."""
    gt = {f"frame{i}": one_of_each() for i in range(2)}
    pred = {token: one_of_each(score=0.9, shift=shift) for token in gt}
    return evaluate_results(gt, pred)


def model(name: str, arch: str, shift: float, layout: str = study.ALL, **runtime: float) -> study.Studied:
    labels = {"front_rear": "front + rear", "left_right": "left + right", "no_front_rear": "without front and rear"}
    layouts = {labels[k]: report(v) for k, v in runtime.items()}
    return study.Studied(name, arch, layout, report(shift), layouts)


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
    ],
)
def test_trained_layout_names_the_papers_reduced_layouts(arch: str, cameras: tuple[str, ...], layout: str) -> None:
    assert study.trained_layout(arch, cameras) == layout


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


def _findings(models: list[study.Studied]) -> dict[str, tuple[str | None, str, bool | None]]:
    return {r["comparison (FDS, 0-48 m)"]: (r["paper"], r["ours"], r["same direction"]) for r in study.findings(models)}


def test_findings_compare_the_models_studied_together() -> None:
    fds = {shift: f"{report(shift).distance[study.FAR].FDS:.3f}" for shift in (0.0, 0.3, 0.8, 1.5)}
    found = _findings(
        [
            model("fb", "fisheye-bevdet", 0.3),
            model("pinhole", "pinhole-bevdet", 0.0),
            model("persp", "fisheye-bevdet-persp", 0.8),
        ]
    )
    assert found == {
        "BEVDet 6 x P vs BEVDet 4 x F, perspective-rectified": ("0.563 vs 0.440", f"{fds[0.0]} vs {fds[0.8]}", True),
        "FisheyeBEVDet vs BEVDet 4 x F, perspective-rectified": ("0.485 vs 0.440", f"{fds[0.3]} vs {fds[0.8]}", True),
        "FisheyeBEVDet vs BEVDet 6 x P": ("0.485 vs 0.563", f"{fds[0.3]} vs {fds[0.0]}", True),
        "FisheyeBEVDet: 0-30 m vs 0-48 m": (
            "0.586 vs 0.485",
            f"{report(0.3).distance[study.NEAR].FDS:.3f} vs {fds[0.3]}",
            report(0.3).distance[study.NEAR].FDS > report(0.3).distance[study.FAR].FDS,
        ),
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
    assert found["FisheyeBEVDet: front + rear vs left + right, run time"][2] is False
    assert found["FisheyeBEVDet: front + rear vs left + right, retrained"][2] is True
    # RF1: the FDS lost without front and rear, pinhole against fisheye (the paper: 0.193 against 0.054)
    lost = "FDS lost without front and rear: BEVDet 6 x P vs FisheyeBEVDet left + right"
    assert found[f"{lost}, run time"] == (
        "0.193 vs 0.054",
        f"{fds[0.0] - fds[0.3]:.3f} vs {fds[0.0] - fds[0.8]:.3f}",
        False,
    )
    assert found[f"{lost}, retrained"] == (
        "0.193 vs 0.054",
        f"{fds[0.0] - fds[1.5]:.3f} vs {fds[0.0] - fds[0.8]:.3f}",
        True,
    )


def test_two_models_of_one_architecture_and_layout_are_refused() -> None:
    study.one_per_layout([model("a", "fisheye-bevdet", 0.0), model("b", "fisheye-bevdet", 0.0, layout="front + rear")])
    with pytest.raises(SystemExit, match="--model a and --model b are both fisheye-bevdet trained with all cameras"):
        study.one_per_layout([model("a", "fisheye-bevdet", 0.0), model("b", "fisheye-bevdet", 0.3)])
