"""The baselines of the paper's Table 2 train like the detector of their family (the BEVDet ones like
FisheyeBEVDet, the PETR ones like FisheyePETR): reduced configurations of each, a few steps through
``fisheye-infer train``, their config files, resumption and the exporter's reading of the run; the BEVDet
baselines' depth targets."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import Rig  # noqa: E402
from fisheye_infer.cli import main  # noqa: E402
from fisheye_infer.models import create_model, load_checkpoint  # noqa: E402
from fisheye_infer.models.training.config_file import write_config  # noqa: E402
from fisheye_infer.models.training.depth import DepthTargets, lidar_frustum  # noqa: E402
from fisheye_infer.models.training.loop import Trainer, read_config_file  # noqa: E402
from fisheye_infer.models.training.options import TrainOptions  # noqa: E402
from fisheye_infer.scenes.scene import Scene  # noqa: E402

BEVDET_BASELINES = ("pinhole-bevdet", "fisheye-bevdet-persp", "fisheye-bevdet-cyl")
PETR_BASELINES = ("pinhole-petr", "fisheye-petr-persp", "fisheye-petr-cyl")
GROUND = -2.0
STEPS = ["--batch-size", "1", "--lr", "1e-3", "--val-frames", "1", "--checkpoint-every", "2"]


def _small(arch: str) -> tuple[Any, Rig]:
    """A reduced baseline (``small_configs``); the cylinder the intended one, as the compact configuration's."""
    from small_configs import small_configs

    config, rig = small_configs()[arch]
    radians = {"azimuth_range": (-math.radians(110), math.radians(110))}
    radians["elevation_range"] = (-math.radians(45), math.radians(45))
    if arch == "fisheye-bevdet-cyl":
        config = config.replace(view_transform=radians)
    if arch == "fisheye-petr-cyl":
        config = config.replace(head=radians)
    if arch == "pinhole-petr":  # the scale ResizeCropFlipImage takes, max(48 / 90, 96 / 160), and its centred crop
        config = config.replace(image_aug={"scale": 0.6, "crop": (0, 6)})
    return config, rig


@pytest.fixture(scope="module", params=BEVDET_BASELINES + PETR_BASELINES)
def inputs(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> tuple[str, Path, Path]:
    """A reduced baseline as an mmdet3d-style file and its rig."""
    config, rig = _small(request.param)
    folder = tmp_path_factory.mktemp(request.param)
    write_config(config, folder / "config.py")
    rig.save(folder / "rig.json")
    return request.param, folder / "config.py", folder / "rig.json"


@pytest.fixture(scope="module")
def run(inputs: tuple[str, Path, Path], tmp_path_factory: pytest.TempPathFactory) -> Path:
    """Four steps, stopped after two and resumed."""
    arch, config, rig = inputs
    out = tmp_path_factory.mktemp(f"{arch}-run") / "run"
    argv = ["train", "--out", str(out), "--steps", "4", *STEPS]
    assert main([*argv, "--config", str(config), "--rig", str(rig), "--until", "2"]) == 0
    assert main([*argv, "--resume"]) == 0
    return out


def test_the_written_config_reads_back_as_its_architecture(inputs: tuple[str, Path, Path]) -> None:
    arch, path, _ = inputs
    assert read_config_file(path) == _small(arch)[0]


def test_a_resumed_run_logs_every_step_with_its_family_terms(inputs: tuple[str, Path, Path], run: Path) -> None:
    rows = [json.loads(line) for line in (run / "log.jsonl").read_text().splitlines()]
    steps = [r for r in rows if "split" not in r]
    assert [r["step"] for r in steps] == [1, 2, 3, 4] and all(np.isfinite(r["loss"]) for r in steps)
    if inputs[0] in BEVDET_BASELINES:
        assert all(r["loss_depth"] > 0 for r in steps)  # every frame has depth targets
    else:
        assert all(r["matched_error"] > 0 and "loss_depth" not in r for r in steps)


def test_the_checkpoint_is_official_format_for_its_architecture(inputs: tuple[str, Path, Path], run: Path) -> None:
    arch = inputs[0]
    state_dict, meta = load_checkpoint(run / "model.pth")
    model = create_model(arch, read_config_file(run / "config.py"), Rig.load(run / "rig.json"))
    assert list(state_dict) == list(model.official_keys())
    assert meta["arch"] == arch and meta["step"] == 4


def test_steps_on_one_batch_lower_its_loss(inputs: tuple[str, Path, Path], tmp_path: Path) -> None:
    """The objective's gradient points downhill, the BEVDet family's depth loss included: eight steps on the same
    frame."""
    arch, config, rig = inputs
    options = TrainOptions(steps=100, batch_size=1, lr=1e-3, warmup_steps=0)
    trainer = Trainer(read_config_file(config), Rig.load(rig), tmp_path / "run", options)
    batch = trainer.train_batches[0]
    terms = [trainer.train_step(batch) for _ in range(8)]
    assert terms[-1]["loss"] < 0.85 * terms[0]["loss"], [t["loss"] for t in terms]
    if arch in BEVDET_BASELINES:
        assert terms[-1]["loss_depth"] < terms[0]["loss_depth"]


def test_the_exporter_opens_the_run_as_its_architecture(inputs: tuple[str, Path, Path], run: Path) -> None:
    """What ``fisheye-infer export --ckpt model.pth --config config.py --rig rig.json`` builds and traces: the
    pinhole and perspective baselines store the same keys, so the written config tells them apart."""
    from fisheye_infer.export.exporter import open_checkpoint

    opened = open_checkpoint(run / "model.pth", config=run / "config.py", rig=run / "rig.json")
    assert opened.entry.name == inputs[0] and opened.model.config == read_config_file(run / "config.py")


# -- depth targets in each baseline's own depth convention ------------------------------------------


def _geometry(arch: str) -> tuple[Any, Any]:
    config, rig = _small(arch)
    return create_model(arch, config, rig).view_transform.geometry, config


def test_a_pinhole_cell_targets_depth_along_the_optical_axis() -> None:
    """A wall 8 m ahead of the lidar, square to the front camera (0.75 m ahead of the lidar): every cell that
    sees it targets the bin of 7.25 m, the depth along the optical axis, however far off-axis it looks."""
    geometry, config = _geometry("pinhole-bevdet")
    wall = np.array([[8.0 + 0.5, 0.0, GROUND, 1.0, 40.0, 20.0, 0.0]])  # near face at x = 8, 18 m high
    targets = DepthTargets(geometry)
    with_wall = targets(Scene(wall, np.zeros(1, np.int64), GROUND))[0]  # the front camera, views in rig order
    ground = targets(Scene(np.zeros((0, 7)), np.zeros(0, np.int64), GROUND))[0]
    start, _, step = config.view_transform.dbound
    wall_cells = (ground == -1) | (ground > with_wall)  # the sky, or ground beyond the wall
    assert wall_cells.sum() >= with_wall.size // 2
    assert np.all(start + step * with_wall[wall_cells] == 7.5), with_wall  # 7.25 m: the bin of 7.5 m


@pytest.mark.parametrize("arch", BEVDET_BASELINES)
def test_a_ground_cell_targets_the_bin_where_its_ray_meets_the_ground(arch: str) -> None:
    """Whatever the geometry's depth (along the axis, along the ray, the cylinder's radius), the target bin's
    point lies where the cell's ray meets the ground, within half a bin."""
    geometry, _ = _geometry(arch)
    bins = DepthTargets(geometry)(Scene(np.zeros((0, 7)), np.zeros(0, np.int64), GROUND))
    points, origins = lidar_frustum(geometry)  # V x D x H x W x 3
    v, h, w = np.nonzero(bins >= 0)
    assert len(v) > 0.2 * bins.size
    ray = points[v, -1, h, w] - origins[v]
    ray /= np.linalg.norm(ray, axis=-1, keepdims=True)
    hit = origins[v] + ray * ((GROUND - origins[v, 2]) / ray[:, 2])[:, None]
    target = points[v, bins[v, h, w], h, w]
    spacing = np.linalg.norm(points[v, 1, h, w] - points[v, 0, h, w], axis=-1)
    assert np.all(np.linalg.norm(target - hit, axis=-1) <= spacing / 2 + 1e-3)
    up = ray[:, 2] >= 0
    assert not up.any()  # no cell looking up has a target
