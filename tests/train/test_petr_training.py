"""fisheye-infer train on a reduced FisheyePETR: the official losses fall, checkpoints export, --resume
continues the same run, the image backbone can start from another run's, and a run can start from one
with fewer queries."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import Rig  # noqa: E402
from fisheye_infer.cli import main  # noqa: E402
from fisheye_infer.models import PETRConfig, create_model, load_checkpoint  # noqa: E402
from fisheye_infer.models.training.loop import Trainer  # noqa: E402
from fisheye_infer.models.training.options import TrainOptions  # noqa: E402
from fisheye_infer.models.training.run_checkpoints import QUERY_TABLE  # noqa: E402
from fisheye_infer.runtime.artifact import read_meta  # noqa: E402

Run = Any


def test_every_term_is_logged(petr_run: Run) -> None:
    rows = [r for r in petr_run.log if "split" not in r]
    assert [r["step"] for r in rows] == [1, 2, 3, 4]
    assert {"loss", "loss_cls", "loss_bbox", "matched_error", "lr", "seconds"} <= set(rows[0])
    assert all(np.isfinite(petr_run.losses()))
    assert [r["step"] for r in petr_run.log if r.get("split") == "val"] == [2, 4]


def test_steps_on_one_batch_lower_its_loss(petr_inputs: tuple[Path, Path], tmp_path: Path) -> None:
    """The objective's gradient points downhill: eight steps on the same two frames."""
    config, rig = PETRConfig.from_mmdet3d_config(petr_inputs[0]), Rig.load(petr_inputs[1])
    trainer = Trainer(config, rig, tmp_path / "run", TrainOptions(steps=100, lr=1e-3, warmup_steps=0))
    batch = trainer.train_batches[0]
    losses = [trainer.train_step(batch)["loss"] for _ in range(8)]
    assert losses[-1] < 0.85 * losses[0], losses


def test_checkpoint_is_official_format_and_records_the_architecture(petr_run: Run) -> None:
    state_dict, meta = load_checkpoint(petr_run.folder / "model.pth")
    config = PETRConfig.from_mmdet3d_config(petr_run.folder / "config.py")
    model = create_model("fisheye-petr", config, Rig.load(petr_run.folder / "rig.json"))
    expected = model.official_keys()
    assert list(state_dict) == list(expected)
    assert all(tuple(v.shape) == expected[k][0] for k, v in state_dict.items())
    assert meta["arch"] == "fisheye-petr" and meta["step"] == 4 and meta["config"] == config.to_dict()
    assert config.image.height == 64  # the written file states the image size


def test_resume_continues_the_uninterrupted_run(petr_resumed: Run, petr_run: Run) -> None:
    np.testing.assert_allclose(petr_resumed.losses(), petr_run.losses(), rtol=1e-4)
    a, _ = load_checkpoint(petr_resumed.folder / "model.pth")
    b, _ = load_checkpoint(petr_run.folder / "model.pth")
    for key in a:
        torch.testing.assert_close(a[key], b[key], rtol=1e-4, atol=1e-5, msg=key)


def test_resume_before_the_first_checkpoint_names_the_missing_file(
    petr_inputs: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    """A FisheyePETR run stopped before its first checkpoint: its folder holds config.py and rig.json only."""
    for path in petr_inputs:
        shutil.copy(path, tmp_path / path.name)
    assert main(["train", "--out", str(tmp_path), "--resume"]) == 1
    assert f"{tmp_path / 'checkpoint.pth'} does not exist" in capsys.readouterr().err


@pytest.mark.slow  # a whole export: make test-fast leaves it out
def test_trained_checkpoint_round_trips_through_export(petr_run: Run, capsys: pytest.CaptureFixture[str]) -> None:
    folder = petr_run.folder
    out = folder / "model.onnx"
    argv = ["export", "--ckpt", str(folder / "model.pth"), "--config", str(folder / "config.py")]
    argv += ["--rig", str(folder / "rig.json"), "--out", str(out), "--frames", "1"]
    assert main(argv) == 0, capsys.readouterr().err
    meta = read_meta(out)
    assert meta.architecture == "fisheye-petr" and meta.parity is not None and meta.parity.passed
    assert meta.image_size == (64, 64)


def test_backbone_starts_from_another_run(petr_run: Run, petr_inputs: tuple[Path, Path], tmp_path: Path) -> None:
    config, rig = PETRConfig.from_mmdet3d_config(petr_inputs[0]), Rig.load(petr_inputs[1])
    options = TrainOptions(steps=1, seed=1, init_backbone=str(petr_run.folder / "model.pth"))
    trainer = Trainer(config, rig, tmp_path / "run", options)
    trainer.load_backbone()
    trained, _ = load_checkpoint(petr_run.folder / "model.pth")
    mine = trainer.model.state_dict()
    for key in [k for k in mine if k.startswith(("img_backbone.", "img_neck."))]:
        torch.testing.assert_close(mine[key], trained[key], msg=key)
    head = "pts_bbox_head.input_proj.weight"
    assert not torch.equal(mine[head], trained[head])  # the head keeps its own seeded start


def test_init_grows_the_query_set(petr_run: Run, petr_inputs: tuple[Path, Path], tmp_path: Path) -> None:
    """--init from a run with fewer queries: its queries come first, the others start as a new run's do."""
    config, rig = PETRConfig.from_mmdet3d_config(petr_inputs[0]), Rig.load(petr_inputs[1])
    have = config.head.num_query
    more = config.replace(head={"num_query": 3 * have})
    start = str(petr_run.folder / "model.pth")
    trainer = Trainer(more, rig, tmp_path / "run", TrainOptions(steps=1, seed=1, init=start))
    seeded = trainer.model.state_dict()[QUERY_TABLE].clone()
    trainer.load_init()
    trained, _ = load_checkpoint(start)
    mine = trainer.model.state_dict()
    table = mine[QUERY_TABLE]
    assert table.shape == (3 * have, 3)
    torch.testing.assert_close(table[:have], trained[QUERY_TABLE], rtol=0, atol=0)
    torch.testing.assert_close(table[have:], seeded[have:], rtol=0, atol=0)
    for key in [k for k in mine if k != QUERY_TABLE]:
        torch.testing.assert_close(mine[key], trained[key], rtol=0, atol=0, msg=key)


def test_init_never_drops_queries(petr_run: Run, petr_inputs: tuple[Path, Path], tmp_path: Path) -> None:
    from fisheye_infer.errors import CheckpointError

    config, rig = PETRConfig.from_mmdet3d_config(petr_inputs[0]), Rig.load(petr_inputs[1])
    fewer = config.replace(head={"num_query": config.head.num_query // 2})
    options = TrainOptions(steps=1, init=str(petr_run.folder / "model.pth"))
    with pytest.raises(CheckpointError, match=r"another model configuration \(differs in: head\)"):
        Trainer(fewer, rig, tmp_path / "run", options).load_init()


def test_a_backbone_of_another_shape_is_refused(
    petr_inputs: tuple[Path, Path], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    from fisheye_infer.models.pretrained import COMPACT_BEVDET  # half-width ResNet-18; the reduced PETR's is full

    argv = ["train", "--out", str(tmp_path / "run"), "--config", str(petr_inputs[0]), "--rig", str(petr_inputs[1])]
    assert main([*argv, "--steps", "1", "--init-backbone", str(COMPACT_BEVDET.checkpoint)]) == 1
    assert "--init-backbone" in (err := capsys.readouterr().err) and "this configuration's is" in err


def test_a_frozen_backbone_stays_as_it_started(petr_run: Run, petr_inputs: tuple[Path, Path], tmp_path: Path) -> None:
    config, rig = PETRConfig.from_mmdet3d_config(petr_inputs[0]), Rig.load(petr_inputs[1])
    start = str(petr_run.folder / "model.pth")
    options = TrainOptions(steps=2, seed=1, init_backbone=start, freeze_backbone=True, val_frames=0)
    trainer = Trainer(config, rig, tmp_path / "run", options)
    head = "pts_bbox_head.input_proj.weight"
    seeded = trainer.model.state_dict()[head].clone()
    trainer.run(progress=lambda _: None)
    trained, _ = load_checkpoint(tmp_path / "run" / "model.pth")
    started, _ = load_checkpoint(start)
    backbone = [k for k in trained if k.startswith(("img_backbone.", "img_neck."))]
    assert any(k.endswith("running_mean") for k in backbone)  # BatchNorm statistics are among them
    for key in backbone:
        torch.testing.assert_close(trained[key], started[key], rtol=0, atol=0, msg=key)
    assert not torch.equal(trained[head], seeded)  # the rest trains


def test_a_frozen_backbone_needs_a_start(petr_inputs: tuple[Path, Path], tmp_path: Path) -> None:
    from fisheye_infer.errors import ConfigError

    config, rig = PETRConfig.from_mmdet3d_config(petr_inputs[0]), Rig.load(petr_inputs[1])
    trainer = Trainer(config, rig, tmp_path / "run", TrainOptions(steps=1, freeze_backbone=True))
    with pytest.raises(ConfigError, match="--freeze-backbone keeps the backbone as it starts"):
        trainer.run(progress=lambda _: None)
