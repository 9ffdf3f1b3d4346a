"""The compact configuration: consistent, written as a config file that reads back, small enough to ship."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.errors import ConfigError  # noqa: E402
from fisheye_infer.models import BEVDetConfig, create_model  # noqa: E402
from fisheye_infer.models.training.compact import compact_bevdet_config, compact_rig, write_config  # noqa: E402

SHIP_LIMIT_BYTES = 20_000_000


@pytest.mark.parametrize("config", [BEVDetConfig(), compact_bevdet_config()], ids=["official", "compact"])
def test_config_file_reads_back_as_the_configuration(config: BEVDetConfig, tmp_path) -> None:
    path = write_config(config, tmp_path / "config.py")
    assert BEVDetConfig.from_mmdet3d_config(path) == config


def test_compact_model_fits_its_rig_and_the_size_limit() -> None:
    config, rig = compact_bevdet_config(), compact_rig()
    assert rig.shared_model().width == config.image.width == 320
    model = create_model("fisheye-bevdet", config, rig)
    size = sum(v.numel() * v.element_size() for v in model.official_state_dict().values())
    assert size < SHIP_LIMIT_BYTES


def test_backbone_width_must_agree_with_the_neck() -> None:
    with pytest.raises(ConfigError, match="neck_in_channels"):
        BEVDetConfig().replace(backbone={"base_channels": 32})
