"""Shared fixtures for the model tests: a reduced FisheyeBEVDet configuration and synthetic checkpoints."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from fisheye_infer.models import BEVDetConfig, load_model, make_checkpoint

DATA = Path(__file__).parent / "data"


def small_bevdet_config() -> BEVDetConfig:
    """Four 160x160 cameras, an 8x32 angular grid, 24 depth bins, a 48 m BEV square of 80x80 cells,
    narrower BEV encoder and head: every stage of the official graph, at a fraction of the cost."""
    return BEVDetConfig().replace(
        image={"height": 160, "width": 160},
        view_transform={"out_channels": 32, "feature_size": (8, 32), "xbound": (-24.0, 24.0, 0.6),
                        "ybound": (-24.0, 24.0, 0.6), "dbound": (0.5, 24.5, 1.0)},
        bev_encoder={"in_channels": 32, "out_channels": (32, 64), "layer_nums": (1, 1),
                     "fpn_in_channels": (32, 64), "fpn_out_channels": (32, 32)},
        head={"in_channels": 64, "hidden_channel": 32, "num_heads": 4, "ffn_channels": 64, "head_conv": 16,
              "num_proposals": 50, "grid_size": (320, 320, 40), "pc_range": (-24.0, -24.0),
              "voxel_size": (0.15, 0.15), "post_center_range": (-26.0, -26.0, -5.0, 26.0, 26.0, 5.0)},
    )


@pytest.fixture(scope="session", autouse=True)
def _threads() -> None:
    torch.set_num_threads(min(2, torch.get_num_threads()))


@pytest.fixture(scope="session")
def small_config() -> BEVDetConfig:
    return small_bevdet_config()


@pytest.fixture(scope="session")
def small_checkpoint(small_config: BEVDetConfig) -> dict:
    return make_checkpoint("fisheye-bevdet", seed=1, config=small_config)


@pytest.fixture()
def small_state_dict(small_checkpoint: dict) -> dict[str, torch.Tensor]:
    """A fresh shallow copy that a test may edit."""
    return dict(small_checkpoint["state_dict"])


@pytest.fixture(scope="session")
def small_model(small_config: BEVDetConfig, small_checkpoint: dict):
    model, _ = load_model("fisheye-bevdet", small_checkpoint, config=small_config)
    return model


@pytest.fixture(scope="session")
def full_checkpoint() -> dict:
    return make_checkpoint("fisheye-bevdet", seed=0)


@pytest.fixture(scope="session")
def full_model(full_checkpoint: dict):
    """(model, geometry report) for the official configuration and the default rig."""
    return load_model("fisheye-bevdet", full_checkpoint)
