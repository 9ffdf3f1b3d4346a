"""Training runs of the reduced FisheyeBEVDet (four 160x160 cameras), once per session."""

from __future__ import annotations

import json
import shutil
from dataclasses import dataclass
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import default_rig  # noqa: E402
from fisheye_infer.cli import main  # noqa: E402
from fisheye_infer.models.training.config_file import write_config  # noqa: E402
from fisheye_infer.scenes.render import resized_rig  # noqa: E402

#: A few steps on tiny frames: batch 1, no warm-up damping worth the name at this rate.
STEPS = ["--batch-size", "1", "--lr", "1e-3", "--val-frames", "1", "--checkpoint-every", "2"]


@dataclass(frozen=True)
class Run:
    folder: Path

    @property
    def log(self) -> list[dict]:
        return [json.loads(line) for line in (self.folder / "log.jsonl").read_text().splitlines()]

    def losses(self) -> list[float]:
        return [row["loss"] for row in self.log if "split" not in row]


@pytest.fixture(scope="session")
def small_inputs(tmp_path_factory: pytest.TempPathFactory, small_bevdet_config) -> tuple[Path, Path]:
    """The reduced configuration as an mmdet3d-style file and the shipped rig resized by 0.2."""
    folder = tmp_path_factory.mktemp("train_inputs")
    write_config(small_bevdet_config, folder / "config.py")
    resized_rig(default_rig(), 0.2).save(folder / "rig.json")
    return folder / "config.py", folder / "rig.json"


def train(
    out: Path, inputs: tuple[Path, Path] | None, steps: int, resume: bool = False, until: int | None = None
) -> Run:
    argv = ["train", "--out", str(out), "--steps", str(steps)] + (["--until", str(until)] if until else [])
    # a resumed run is given none of its options again: it keeps those it was started with
    argv += ["--resume"] if resume else [*STEPS, "--config", str(inputs[0]), "--rig", str(inputs[1])]  # type: ignore[index]
    assert main(argv) == 0
    return Run(out)


@pytest.fixture(scope="session")
def straight_run(tmp_path_factory: pytest.TempPathFactory, small_inputs: tuple[Path, Path]) -> Run:
    """Four steps in one go."""
    return train(tmp_path_factory.mktemp("straight") / "run", small_inputs, 4)


@pytest.fixture(scope="session")
def resumed_run(tmp_path_factory: pytest.TempPathFactory, small_inputs: tuple[Path, Path]) -> tuple[Run, Run]:
    """A four-step run stopped after step 2, then (from a copy of that folder) resumed: (the stopped run, the resumed one)."""
    first = train(tmp_path_factory.mktemp("first") / "run", small_inputs, 4, until=2)
    copy = tmp_path_factory.mktemp("resumed") / "run"
    shutil.copytree(first.folder, copy)
    return first, train(copy, None, 4, resume=True)


@pytest.fixture(scope="session")
def petr_inputs(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path]:
    """The reduced FisheyePETR (four 64x64 cameras) as an mmdet3d-style file and its rig."""
    from small_configs import small_configs

    config, rig = small_configs()["fisheye-petr"]
    folder = tmp_path_factory.mktemp("petr_inputs")
    write_config(config, folder / "config.py")
    rig.save(folder / "rig.json")
    return folder / "config.py", folder / "rig.json"


@pytest.fixture(scope="session")
def petr_run(tmp_path_factory: pytest.TempPathFactory, petr_inputs: tuple[Path, Path]) -> Run:
    """Four FisheyePETR steps in one go."""
    return train(tmp_path_factory.mktemp("petr") / "run", petr_inputs, 4)


@pytest.fixture(scope="session")
def petr_resumed(tmp_path_factory: pytest.TempPathFactory, petr_inputs: tuple[Path, Path]) -> Run:
    """A four-step FisheyePETR run stopped after step 2 and resumed."""
    run = train(tmp_path_factory.mktemp("petr_first") / "run", petr_inputs, 4, until=2)
    return train(run.folder, None, 4, resume=True)
