"""fisheye-infer train --init: a run that starts from a checkpoint's weights."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from typing import Any  # noqa: E402

from fisheye_infer.cli import main  # noqa: E402
from fisheye_infer.models import load_checkpoint  # noqa: E402

Run = Any


@pytest.fixture(scope="module")
def fine_tuned(tmp_path_factory: pytest.TempPathFactory, straight_run: Run) -> Path:
    """One step from the straight run's weights at a learning rate too small to move them."""
    out = tmp_path_factory.mktemp("fine_tuned") / "run"
    folder = straight_run.folder
    argv = [
        "train",
        "--out",
        str(out),
        "--init",
        str(folder / "model.pth"),
        "--config",
        str(folder / "config.py"),
        "--rig",
        str(folder / "rig.json"),
        "--steps",
        "1",
        "--batch-size",
        "1",
        "--lr",
        "1e-12",
        "--val-frames",
        "0",
    ]
    assert main(argv) == 0
    return out


def test_init_starts_from_the_checkpoint_and_records_it(fine_tuned: Path, straight_run: Run) -> None:
    start, _ = load_checkpoint(straight_run.folder / "model.pth")
    tuned, meta = load_checkpoint(fine_tuned / "model.pth")
    assert meta["step"] == 1 and meta["train_options"]["init"] == str(straight_run.folder / "model.pth")
    for key, value in start.items():
        if value.is_floating_point() and "running" not in key:  # batch statistics move with any training-mode forward
            torch.testing.assert_close(tuned[key], value, rtol=0, atol=1e-6, msg=key)
    # both first steps see the same frame: the straight run's from the seeded initialiser (which would
    # give its loss again, exactly), this one from its trained weights
    first = json.loads(fine_tuned.joinpath("log.jsonl").read_text().splitlines()[0])
    assert first["step"] == 1 and first["loss"] < 0.9 * straight_run.losses()[0]


def test_a_fine_tuning_run_resumes_and_keeps_its_origin(fine_tuned: Path, tmp_path: Path, straight_run: Run) -> None:
    copy = tmp_path / "run"
    shutil.copytree(fine_tuned, copy)
    assert (
        main(
            [
                "train",
                "--out",
                str(copy),
                "--resume",
                "--steps",
                "2",
                "--batch-size",
                "1",
                "--lr",
                "1e-12",
                "--val-frames",
                "0",
            ]
        )
        == 0
    )
    _, meta = load_checkpoint(copy / "model.pth")
    assert meta["step"] == 2 and meta["train_options"]["init"] == str(straight_run.folder / "model.pth")


@pytest.mark.parametrize(
    ("extra", "message"),
    [
        (["--init", "nowhere.pth"], "--init: nowhere.pth does not exist"),
        (["--resume", "--init", "x.pth"], "leave out --init"),
    ],
)
def test_bad_init_options_are_named(
    extra: list[str], message: str, tmp_path: Path, straight_run: Run, capsys: pytest.CaptureFixture[str]
) -> None:
    folder = straight_run.folder
    inputs = [] if "--resume" in extra else ["--config", str(folder / "config.py"), "--rig", str(folder / "rig.json")]
    assert main(["train", "--out", str(tmp_path / "run"), *inputs, "--steps", "1", *extra]) == 1
    assert message in capsys.readouterr().err


def test_init_from_another_configuration_is_refused(
    tmp_path: Path, straight_run: Run, capsys: pytest.CaptureFixture[str]
) -> None:
    # the compact configuration (the default) from the small configuration's checkpoint
    assert (
        main(
            ["train", "--out", str(tmp_path / "run"), "--init", str(straight_run.folder / "model.pth"), "--steps", "1"]
        )
        == 1
    )
    assert "was trained with another model configuration" in capsys.readouterr().err
