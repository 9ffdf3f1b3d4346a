"""Lens-centre jitter (``train --lens-jitter``): each step's frames rendered through moved lenses, the model
given exactly those lenses' tables (FisheyeBEVDet: warp taps and depth masks; FisheyePETR: warp taps, key mask
and its key embedding), seeded per step; refused where it moves nothing."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import Rig  # noqa: E402
from fisheye_infer.cli import main  # noqa: E402
from fisheye_infer.errors import ConfigError  # noqa: E402
from fisheye_infer.geometry.lss import LSSGeometry  # noqa: E402
from fisheye_infer.geometry.petr import PETRGeometry  # noqa: E402
from fisheye_infer.geometry.tables import PETR_KEY_MASK  # noqa: E402
from fisheye_infer.models import create_model  # noqa: E402
from fisheye_infer.models.training.batches import Batch  # noqa: E402
from fisheye_infer.models.training.config_file import write_config  # noqa: E402
from fisheye_infer.models.training.depth import DepthTargets  # noqa: E402
from fisheye_infer.models.training.lens_jitter import centres_moved  # noqa: E402
from fisheye_infer.models.training.loop import Trainer  # noqa: E402
from fisheye_infer.models.training.objectives import PETRObjective, objective_for  # noqa: E402
from fisheye_infer.models.training.options import TrainOptions  # noqa: E402
from fisheye_infer.scenes.render import Renderer  # noqa: E402
from fisheye_infer.scenes.scene import random_scene  # noqa: E402

PIXELS = 3.0


@pytest.fixture(scope="module")
def small() -> tuple[Any, Rig]:
    from small_configs import small_configs

    config, rig = small_configs()["fisheye-bevdet"]
    return config, rig


@pytest.fixture(scope="module")
def trainer(small: tuple[Any, Rig], tmp_path_factory: pytest.TempPathFactory) -> Trainer:
    config, rig = small
    options = TrainOptions(steps=10, batch_size=2, lens_jitter=PIXELS)
    return Trainer(config, rig, tmp_path_factory.mktemp("jitter") / "run", options)


def test_moving_the_centres_keeps_everything_else(small: tuple[Any, Rig]) -> None:
    rig = small[1]
    shifts = np.array([[1.5, -2.0], [0.0, 0.25], [-3.0, 3.0], [2.0, 0.0]])
    moved = centres_moved(rig, shifts)
    assert moved.names == rig.names and np.array_equal(moved.cam2lidar(), rig.cam2lidar())
    for cam, new, (rows, cols) in zip(rig.cameras, moved.cameras, shifts):
        assert new.model.center_row == cam.model.center_row + rows
        assert new.model.center_col == cam.model.center_col + cols
        keep = {"center_row", "center_col"}
        assert {k: v for k, v in new.model.model_dump().items() if k not in keep} == {
            k: v for k, v in cam.model.model_dump().items() if k not in keep
        }
    with pytest.raises(ConfigError, match=r"one \(rows, cols\) offset per camera, \(4, 2\)"):
        centres_moved(rig, shifts[:3])


def test_a_moved_centre_moves_the_picture_by_as_many_pixels(small: tuple[Any, Rig]) -> None:
    """What jitter varies is where the picture lies in the frame: whole-pixel moves of the centre give the same
    picture, moved (the premise of the option)."""
    rig = small[1].subset(small[1].names[:1])
    scene = random_scene(np.random.default_rng(5))
    before = Renderer().render(rig, scene)[rig.names[0]]
    after = Renderer().render(centres_moved(rig, np.array([[3.0, -2.0]])), scene)[rig.names[0]]
    assert np.array_equal(after[3:, :-2], before[:-3, 2:])
    assert not np.array_equal(after, before)


def test_a_step_is_rendered_through_its_moved_lenses_with_their_tables_and_depth_masks(trainer: Trainer) -> None:
    jitter = trainer.train_batches.jitter
    assert jitter is not None
    step = 3
    lenses = jitter(step)
    shifts = jitter.shifts(step)
    assert shifts.shape == (4, 2) and np.all(np.abs(shifts) <= PIXELS) and len(np.unique(shifts)) == 8
    assert np.array_equal(shifts, jitter.shifts(step)) and not np.array_equal(shifts, jitter.shifts(step + 1))
    assert np.array_equal(lenses.rig.cam2lidar(), trainer.rig.cam2lidar())

    batch = trainer.train_batches[step]
    params = trainer.model.view_transform.geometry.params
    exact = LSSGeometry.from_rig(lenses.rig, params)  # a geometry built for the moved lenses from scratch
    assert batch.lenses is not None and set(batch.lenses.tables) == set(exact.sampling_tables())
    for name, table in exact.sampling_tables().items():
        assert np.array_equal(batch.lenses.tables[name], table), name
    for i, sample in enumerate(batch.samples):
        assert sample.index == 2 * step + i
        assert np.array_equal(sample.images, trainer.train_frames.frame(sample.index, lenses.rig).images)
        assert not np.array_equal(sample.images, trainer.train_frames[sample.index].images)
    targets = DepthTargets(exact)
    assert batch.depth is not None
    assert np.array_equal(batch.depth, np.concatenate([targets(s.scene) for s in batch.samples]))


def test_the_forward_with_a_steps_tables_is_that_of_a_model_built_for_its_lenses(
    trainer: Trainer, small: tuple[Any, Rig]
) -> None:
    batch = trainer.train_batches[1]
    assert batch.lenses is not None
    built = create_model("fisheye-bevdet", small[0], batch.lenses.rig)
    built.load_state_dict(trainer.model.state_dict())
    images = torch.from_numpy(np.stack([s.images for s in batch.samples]))
    tables = {k: torch.from_numpy(v) for k, v in batch.lenses.tables.items()}
    trainer.model.eval()
    built.eval()
    with torch.no_grad():
        given = trainer.model.forward_raw(images, tables=tables)
        installed = trainer.model.forward_raw(images)
        expected = built.forward_raw(images)
    for name in expected:
        torch.testing.assert_close(given[name], expected[name], rtol=1e-5, atol=1e-5, msg=name)
    assert any(not torch.allclose(installed[n], expected[n], rtol=1e-5, atol=1e-5) for n in expected)


@pytest.fixture(scope="module")
def petr_trainer(tmp_path_factory: pytest.TempPathFactory) -> Trainer:
    from small_configs import small_configs

    config, rig = small_configs()["fisheye-petr"]
    options = TrainOptions(steps=10, batch_size=2, lens_jitter=PIXELS)
    return Trainer(config, rig, tmp_path_factory.mktemp("petr-jitter") / "run", options)


def test_a_petr_step_gets_its_lenses_warp_taps_and_key_mask(petr_trainer: Trainer) -> None:
    step = 2
    batch = petr_trainer.train_batches[step]
    assert batch.lenses is not None and batch.depth is None
    head = petr_trainer.model.pts_bbox_head
    exact = PETRGeometry.from_rig(batch.lenses.rig, head.geometry.params)  # built for the moved lenses from scratch
    assert set(batch.lenses.tables) == set(exact.lens_tables()) == {*exact.sampling_tables(), PETR_KEY_MASK}
    for name, table in exact.lens_tables().items():
        assert np.array_equal(batch.lenses.tables[name], table), name
    assert np.array_equal(batch.lenses.inside_lens, ~exact.key_mask())
    assert not np.array_equal(exact.key_mask(), head.geometry.key_mask())  # the step masks other keys
    for i, sample in enumerate(batch.samples):
        assert np.array_equal(sample.images, petr_trainer.train_frames.frame(2 * step + i, batch.lenses.rig).images)


def test_a_petr_step_decodes_as_a_model_built_for_its_lenses(petr_trainer: Trainer) -> None:
    """The training forward with a step's lenses (warp taps, key mask, the key embedding of that mask) is the
    forward of a model built for the moved rig with the same weights."""
    batch = petr_trainer.train_batches[1]
    assert batch.lenses is not None
    model = petr_trainer.model
    built = create_model("fisheye-petr", model.config, batch.lenses.rig)
    built.load_state_dict(model.state_dict())
    images = torch.from_numpy(np.stack([s.images for s in batch.samples]))
    outputs = {}
    model.eval()
    built.eval()
    cases = {"step": (model, batch.lenses), "built": (built, None), "rig": (model, None)}
    with torch.no_grad():
        for name, (m, lenses) in cases.items():
            objective = objective_for(m, petr_trainer.options)
            assert isinstance(objective, PETRObjective)
            tables, positions = objective.step_tables(lenses, torch.device("cpu"))
            feats = m.image_features(images)
            outputs[name] = m.pts_bbox_head.forward_decoder(feats, tables=tables, positions=positions)
    torch.testing.assert_close(outputs["step"], outputs["built"], rtol=1e-5, atol=1e-5)
    assert not torch.allclose(outputs["rig"], outputs["built"], rtol=1e-5, atol=1e-5)


def test_a_jittered_petr_run_trains_and_keeps_the_rigs_tables(petr_trainer: Trainer) -> None:
    head = petr_trainer.model.pts_bbox_head
    installed = {name: table.clone() for name, table in head.tables().items()}
    for _ in range(2):
        assert np.isfinite(petr_trainer.train_step()["loss"])
    petr_trainer.objective.settle()
    assert torch.equal(head.tables()[PETR_KEY_MASK], installed[PETR_KEY_MASK])  # the exported file's rig
    for name in installed.keys() - {PETR_KEY_MASK, "geom.petr.key_pos"}:
        assert torch.equal(head.tables()[name], installed[name]), name


def test_without_jitter_a_step_is_the_frames_of_the_rig(small: tuple[Any, Rig], tmp_path: Path) -> None:
    trainer = Trainer(*small, tmp_path / "run", TrainOptions(steps=10, batch_size=1))
    batch = trainer.train_batches[2]
    assert isinstance(batch, Batch) and batch.lenses is None and trainer.train_batches.jitter is None
    assert np.array_equal(batch.samples[0].images, trainer.train_frames[2].images)


def test_jitter_is_refused_where_it_moves_no_lens(tmp_path: Path) -> None:
    from small_configs import small_configs

    for arch in ("fisheye-bevdet-cyl", "fisheye-petr-persp", "pinhole-petr"):
        config, rig = small_configs()[arch]
        with pytest.raises(ConfigError, match=f"--lens-jitter: moves the lenses of fisheye-bevdet.*; {arch} trains"):
            Trainer(config, rig, tmp_path / arch, TrainOptions(lens_jitter=2.0))
    for pixels in (-1.0, 64.0):
        with pytest.raises(ConfigError, match="--lens-jitter: expected 0 to 32 pixels"):
            TrainOptions(lens_jitter=pixels)


def test_a_jittered_run_resumes_with_its_jitter_and_refuses_another(
    small: tuple[Any, Rig], tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    config, rig = small
    write_config(config, tmp_path / "config.py")
    rig.save(tmp_path / "rig.json")
    out = tmp_path / "run"
    argv = ["train", "--out", str(out), "--steps", "3", "--batch-size", "1", "--val-frames", "1"]
    first = [*argv, "--config", str(tmp_path / "config.py"), "--rig", str(tmp_path / "rig.json")]
    assert main([*first, "--lens-jitter", "2", "--until", "2"]) == 0
    assert main([*argv, "--resume", "--lens-jitter", "3"]) != 0
    assert "--lens-jitter: saved 2.0, given 3.0" in capsys.readouterr().err
    assert main([*argv, "--resume"]) == 0
    assert torch.load(out / "checkpoint.pth", weights_only=True)["meta"]["train_options"]["lens_jitter"] == 2.0


def test_new_lenses_keep_the_geometrys_poses(small: tuple[Any, Rig], trainer: Trainer, petr_trainer: Trainer) -> None:
    from small_configs import move_rig

    for geometry, builder in (
        (trainer.model.view_transform.geometry, "LSSGeometry.from_rig"),
        (petr_trainer.model.pts_bbox_head.geometry, "PETRGeometry.from_rig"),
    ):
        with pytest.raises(ConfigError, match=f"its camera poses differ from the geometry's.*{builder}"):
            geometry.with_lenses(move_rig(small[1]))
