"""fisheye-infer train on tiny frames: the loss falls, checkpoints export, --resume continues the same run."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from typing import Any  # noqa: E402

from small_configs import own_lenses  # noqa: E402

from fisheye_infer.cameras.rig import Rig, pinhole_rig  # noqa: E402
from fisheye_infer.cli import main  # noqa: E402
from fisheye_infer.models import BEVDetConfig, create_model, load_checkpoint, load_model  # noqa: E402
from fisheye_infer.models.training.options import lr_factor  # noqa: E402
from fisheye_infer.runtime.artifact import read_meta  # noqa: E402
from fisheye_infer.scenes.render import resized_rig  # noqa: E402

Run = Any


def test_loss_falls_over_a_few_steps(straight_run: Run) -> None:
    losses = straight_run.losses()
    assert len(losses) == 4 and all(np.isfinite(losses))
    assert max(losses[2:]) < 0.5 * losses[0], losses


def test_log_has_every_term_and_a_validation_line_at_each_checkpoint(straight_run: Run) -> None:
    rows = straight_run.log
    train_rows = [r for r in rows if "split" not in r]
    assert [r["step"] for r in train_rows] == [1, 2, 3, 4]
    assert {"loss", "loss_heatmap", "loss_cls", "loss_bbox", "matched_iou", "lr", "seconds"} <= set(train_rows[0])
    assert [r["step"] for r in rows if r.get("split") == "val"] == [2, 4]
    assert [r["lr"] for r in train_rows] == pytest.approx([1e-3 * lr_factor(i, 4, 500) for i in range(4)])


def test_learning_rate_warms_up_then_anneals() -> None:
    assert lr_factor(0, 10_000, 500) == pytest.approx(1 / 3)
    assert lr_factor(250, 10**9, 500) == pytest.approx(2 / 3)
    assert lr_factor(500, 10**9, 500) == pytest.approx(1.0)
    assert lr_factor(5_000, 10_000, 500) == pytest.approx(0.5, abs=1e-3)
    assert lr_factor(10_000, 10_000, 500) == pytest.approx(2e-4)


def test_checkpoint_is_official_format_for_its_config(straight_run: Run) -> None:
    state_dict, meta = load_checkpoint(straight_run.folder / "model.pth")
    config = BEVDetConfig.from_mmdet3d_config(straight_run.folder / "config.py")
    model = create_model("fisheye-bevdet", config, Rig.load(straight_run.folder / "rig.json"))
    expected = model.official_keys()
    assert list(state_dict) == list(expected)
    assert all(tuple(v.shape) == expected[k][0] and v.dtype == expected[k][1] for k, v in state_dict.items())
    assert meta["step"] == 4 and meta["synthetic"] is False and meta["config"] == config.to_dict()


@pytest.mark.slow  # a whole export: make test-fast leaves it out
def test_trained_checkpoint_round_trips_through_export(straight_run: Run, capsys: pytest.CaptureFixture[str]) -> None:
    folder = straight_run.folder
    out = folder / "model.onnx"
    argv = [
        "export",
        "--ckpt",
        str(folder / "model.pth"),
        "--config",
        str(folder / "config.py"),
        "--rig",
        str(folder / "rig.json"),
        "--out",
        str(out),
        "--frames",
        "1",
    ]
    assert main(argv) == 0, capsys.readouterr().err
    meta = read_meta(out)
    assert meta.parity is not None and meta.parity.passed
    assert meta.image_size == (160, 160) and meta.num_boxes == 50 and meta.rig == Rig.load(folder / "rig.json")


def test_resume_continues_from_the_saved_step(resumed_run: tuple[Run, Run], straight_run: Run) -> None:
    first, resumed = resumed_run
    assert [r["step"] for r in resumed.log if "split" not in r] == [1, 2, 3, 4]
    assert resumed.losses()[:2] == first.losses()
    # same frames, same optimiser state: the resumed run is the uninterrupted one
    np.testing.assert_allclose(resumed.losses(), straight_run.losses(), rtol=1e-4)
    a, meta = load_checkpoint(resumed.folder / "model.pth")
    b, _ = load_checkpoint(straight_run.folder / "model.pth")
    assert meta["step"] == 4
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=1e-4, atol=1e-5, msg=key)


def test_resume_drops_the_lines_logged_after_the_checkpoint(resumed_run: tuple[Run, Run], tmp_path: Path) -> None:
    """A run killed between checkpoints has logged steps its checkpoint.pth does not hold; they run again."""
    import json
    import shutil

    first, _ = resumed_run
    killed = tmp_path / "run"
    shutil.copytree(first.folder, killed)
    with (killed / "log.jsonl").open("a") as log:
        log.write(json.dumps({"step": 3, "loss": 1.0}) + "\n")  # step 3 done, its checkpoint never written
    assert main(["train", "--out", str(killed), "--steps", "4", "--resume"]) == 0
    rows = [json.loads(line) for line in (killed / "log.jsonl").read_text().splitlines()]
    steps = [r for r in rows if "split" not in r]
    assert [r["step"] for r in steps] == [1, 2, 3, 4] and steps[2]["loss"] != 1.0


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["--resume"], "has no config.py and rig.json"),
        (["--config", "x.py"], "--config needs --rig"),
        (["--steps", "0"], "--steps: expected at least 1"),
        (["--until", "0"], "--until: expected a step of at least 1"),
        (["--threads", "0"], "--threads: expected at least 1"),
    ],
)
def test_bad_options_are_named(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    assert main(["train", "--out", str(tmp_path / "run"), *argv]) == 1
    assert message in capsys.readouterr().err


def test_a_finished_folder_is_not_overwritten(straight_run: Run, capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["train", "--out", str(straight_run.folder)]) == 1
    assert "pass --resume" in capsys.readouterr().err


def test_resume_with_other_options_is_refused(resumed_run: tuple[Run, Run], capsys: pytest.CaptureFixture[str]) -> None:
    _, resumed = resumed_run
    assert main(["train", "--out", str(resumed.folder), "--resume", "--steps", "5", "--batch-size", "2"]) == 1
    assert "--batch-size: saved 1, given 2" in capsys.readouterr().err


def test_a_reduced_layout_trains_on_the_cameras_named(
    tmp_path: Path, small_inputs: tuple[Path, Path], capsys: pytest.CaptureFixture[str]
) -> None:
    """--cameras: the paper's two-camera layouts retrained, the rig and the config file of those cameras alone."""
    config_file, rig_file = small_inputs
    front_rear = ["fisheye_camera_front", "fisheye_camera_rear"]
    out = tmp_path / "run"
    argv = ["train", "--out", str(out), "--steps", "2", "--batch-size", "1", "--val-frames", "1"]
    argv += ["--config", str(config_file), "--rig", str(rig_file)]
    assert main([*argv, "--cameras", ",".join(front_rear)]) == 0
    rig, full = Rig.load(out / "rig.json"), Rig.load(rig_file)
    assert rig.names == front_rear and all(rig.camera(c) == full.camera(c) for c in front_rear)
    config = BEVDetConfig.from_mmdet3d_config(out / "config.py")
    assert list(config.image.camera_names) == front_rear
    state_dict, _ = load_checkpoint(out / "model.pth")
    expected = create_model("fisheye-bevdet", config, rig).official_keys()
    assert list(state_dict) == list(expected) and all(tuple(v.shape) == expected[k][0] for k, v in state_dict.items())
    assert main(["train", "--out", str(out), "--resume", "--steps", "3", "--cameras", "fisheye_camera_front"]) == 1
    assert "leave out --config, --rig and --cameras" in capsys.readouterr().err
    assert main([*argv[:2], str(tmp_path / "other"), *argv[3:], "--cameras", "fisheye_camera_front,front"]) == 1
    assert (
        "camera 'front': not in the rig (cameras: fisheye_camera_front, fisheye_camera_left" in capsys.readouterr().err
    )


def test_the_compact_configuration_trains_for_a_rig_of_ones_own(tmp_path: Path, moved_rig: Rig) -> None:
    """--rig without --config: the compact FisheyeBEVDet for another rig (every camera moved and with a lens of its
    own, images half the shipped size), its images scaled by 0.4 as the shipped rig's are. The checkpoint's official
    grid is the first camera's; loaded back, every camera keeps its own."""
    mine = resized_rig(own_lenses(moved_rig), 0.5)
    mine.save(tmp_path / "mine.json")
    out = tmp_path / "run"
    argv = ["train", "--out", str(out), "--rig", str(tmp_path / "mine.json"), "--steps", "1", "--val-frames", "0"]
    assert main(argv) == 0
    rig = Rig.load(out / "rig.json")
    assert rig.hash == resized_rig(mine, 0.4).hash and rig.names == mine.names
    config = BEVDetConfig.from_mmdet3d_config(out / "config.py")
    assert (config.image.width, config.image.height) == (160, 160) and list(config.image.camera_names) == rig.names
    state_dict, _ = load_checkpoint(out / "model.pth")
    assert list(state_dict) == list(create_model("fisheye-bevdet", config, rig).official_keys())
    with pytest.warns(UserWarning, match="fisheye_camera_left, fisheye_camera_right, fisheye_camera_rear have lenses"):
        model, report = load_model("fisheye-bevdet", out / "model.pth", config, rig)
    grids = model.view_transform.geometry.grid
    assert report.source == "checkpoint" and np.array_equal(grids[0], state_dict["view_transform.sphere_grid_2d"])
    assert np.array_equal(grids, model.rig_geometry.grid) and not np.array_equal(grids[1], grids[0])


def _two_sizes(rig: Rig) -> Rig:
    """``rig`` with its left camera's images 1280x960."""
    data = rig.model_dump(mode="json")
    data["cameras"][1]["model"].update(width=1280, height=960)
    return Rig.from_dict(data)


def _five_by_four(rig: Rig) -> Rig:
    """``rig`` with 1280x1024 images, which 0.4 does not scale to whole pixels at the same aspect."""
    data = rig.model_dump(mode="json")
    for camera in data["cameras"]:
        camera["model"].update(width=1280, height=1024)
    return Rig.from_dict(data)


@pytest.mark.parametrize(
    ("arch", "make", "message"),
    [
        (
            "fisheye-bevdet-persp",
            _five_by_four,
            "does not give a whole image with the same aspect (1280x1024 -> 512x410)",
        ),
        ("pinhole-bevdet", lambda rig: rig, "the compact pinhole-bevdet takes the shipped six-camera pinhole rig only"),
        ("fisheye-bevdet", lambda _: pinhole_rig(), "camera 'nu_rgb_camera_front' has a pinhole model"),
        ("fisheye-petr", _two_sizes, "camera 'fisheye_camera_left' takes 1280x960 images, camera"),
    ],
)
def test_a_rig_the_compact_configuration_cannot_take_is_named(
    arch: str, make: Any, message: str, rig: Rig, tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    make(rig).save(tmp_path / "rig.json")
    assert main(["train", "--arch", arch, "--rig", str(tmp_path / "rig.json"), "--out", str(tmp_path / "run")]) == 1
    assert message in capsys.readouterr().err and not (tmp_path / "run").exists()
