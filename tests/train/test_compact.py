"""The compact configurations: consistent, written as config files that read back, small enough to ship."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.cameras.rig import Rig, default_rig  # noqa: E402
from fisheye_infer.commands.train import ARCHITECTURES  # noqa: E402
from fisheye_infer.errors import ConfigError  # noqa: E402
from fisheye_infer.models import BEVDetConfig, create_model, get_model_entry  # noqa: E402
from fisheye_infer.models.training.compact import COMPACT, compact_setup  # noqa: E402
from fisheye_infer.models.training.config_file import write_config  # noqa: E402
from fisheye_infer.models.training.loop import TRAINABLE, read_config_file  # noqa: E402
from fisheye_infer.scenes.render import resized_rig  # noqa: E402

#: What a shipped checkpoint may weigh (the compact FisheyePETR: 21.6 MB, the BEVDet family: 14.4 MB).
SHIP_LIMIT_BYTES = 25_000_000


def test_every_trainable_architecture_has_a_compact_configuration_and_a_name_on_the_command_line() -> None:
    assert tuple(COMPACT) == TRAINABLE == tuple(ARCHITECTURES)


@pytest.mark.parametrize("arch", TRAINABLE)
@pytest.mark.parametrize("size", ["official", "compact"])
def test_config_file_reads_back_as_the_configuration_of_its_architecture(arch: str, size: str, tmp_path) -> None:
    config = get_model_entry(arch).config_cls() if size == "official" else compact_setup(arch)[0]
    path = write_config(config, tmp_path / "config.py")
    assert read_config_file(path) == config


@pytest.mark.parametrize("arch", TRAINABLE)
def test_compact_model_fits_its_rig_and_the_size_limit(arch: str) -> None:
    config, rig = compact_setup(arch)
    assert rig.cameras[0].model.width == config.image.width and tuple(rig.names) == config.image.camera_names
    model = create_model(arch, config, rig)
    size = sum(v.numel() * v.element_size() for v in model.official_state_dict().values())
    assert size < SHIP_LIMIT_BYTES


@pytest.mark.parametrize("arch", [a for a in TRAINABLE if not a.startswith("pinhole")])
def test_a_fisheye_architecture_takes_a_rig_of_ones_own(arch: str, moved_rig: Rig) -> None:
    """``compact_setup(arch, rig)``: the rig's images scaled by 0.4 and its cameras in the configuration; the shipped
    rig given so is the default."""
    mine = resized_rig(moved_rig, 0.5)
    config, rig = compact_setup(arch, mine)
    assert rig.hash == resized_rig(mine, 0.4).hash
    assert (config.image.width, config.image.height) == (160, 160) and config.image.camera_names == tuple(rig.names)
    assert create_model(arch, config, rig).geometry_tables()  # the tables of this rig
    (default_config, default), (given_config, given) = compact_setup(arch), compact_setup(arch, default_rig())
    assert default_config == given_config and default.hash == given.hash


def test_the_baselines_keep_the_official_share_of_feature_cells() -> None:
    """Each compact input is the official one scaled by 0.4: feature cells per model in the official ratio."""

    def cells(config) -> int:
        grid = config.view_transform if hasattr(config, "view_transform") else config.head  # the lift or the keys
        return config.num_views * grid.feature_size[0] * grid.feature_size[1]

    compact = {arch: cells(compact_setup(arch)[0]) for arch in TRAINABLE}
    official = {arch: cells(get_model_entry(arch).config_cls()) for arch in compact}
    assert (
        compact
        == {a: official[a] * 0.16 for a in official}
        == {
            "fisheye-bevdet": 1600,
            "fisheye-petr": 1600,
            "pinhole-bevdet": 1200,
            "fisheye-bevdet-persp": 800,
            "fisheye-bevdet-cyl": 800,
            "pinhole-petr": 1200,
            "fisheye-petr-persp": 800,
            "fisheye-petr-cyl": 800,
        }
    )


def test_backbone_width_must_agree_with_the_neck() -> None:
    with pytest.raises(ConfigError, match="neck_in_channels"):
        BEVDetConfig().replace(backbone={"base_channels": 32})
