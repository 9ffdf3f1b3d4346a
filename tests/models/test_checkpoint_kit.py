"""The checkpoint kit rebuilt by ``calibrated_checkpoint``, and loading details it exercises."""

from __future__ import annotations

import hashlib
from pathlib import Path

import pytest
import torch
from checkpoint_kit import kit_checkpoint

from fisheye_infer.errors import CheckpointError
from fisheye_infer.models import load_model

#: sha256 over (key, tensor bytes) of the kit's own make_checkpoint.py output, seed 0.
KIT_DIGESTS = {"fisheye-bevdet": "ad4ebb314855d9e6", "fisheye-petr": "17d2cd669e4d8bfe"}


def _digest(state_dict: dict[str, torch.Tensor]) -> str:
    h = hashlib.sha256()
    for key, value in state_dict.items():
        h.update(key.encode())
        h.update(value.contiguous().numpy().tobytes())
    return h.hexdigest()[:16]


@pytest.mark.parametrize("arch", sorted(KIT_DIGESTS))
def test_rebuilt_kit_is_bit_for_bit_the_kits(arch: str, tmp_path: Path) -> None:
    ckpt = torch.load(kit_checkpoint(arch, tmp_path / "kit.pth"), weights_only=True)
    assert _digest(ckpt["state_dict"]) == KIT_DIGESTS[arch]


@pytest.fixture(scope="module")
def kit_bevdet(tmp_path_factory: pytest.TempPathFactory) -> dict[str, torch.Tensor]:
    path = kit_checkpoint("fisheye-bevdet", tmp_path_factory.mktemp("kit") / "bevdet.pth")
    return torch.load(path, weights_only=True)["state_dict"]


def test_one_element_counters_load_as_pytorch_loads_them(kit_bevdet: dict[str, torch.Tensor]) -> None:
    """Older checkpoints store num_batches_tracked as shape [1]; torch's load_state_dict takes it."""
    old = {k: v.reshape(1) if k.endswith("num_batches_tracked") else v for k, v in kit_bevdet.items()}
    model, _ = load_model("fisheye-bevdet", old)
    assert int(model.img_backbone.bn1.num_batches_tracked) == 4
    assert model.img_backbone.bn1.num_batches_tracked.shape == ()


def test_real_shape_mismatches_are_still_named(kit_bevdet: dict[str, torch.Tensor]) -> None:
    bad = dict(kit_bevdet)
    bad["img_backbone.bn1.num_batches_tracked"] = torch.tensor([4, 4])
    bad["img_backbone.bn1.running_mean"] = bad["img_backbone.bn1.running_mean"][:1]
    with pytest.raises(
        CheckpointError,
        match=r"running_mean: checkpoint \[1\], model \[64\](.|\n)*img_backbone\.bn1\.num_batches_tracked: checkpoint \[2\], model \[\]",
    ):
        load_model("fisheye-bevdet", bad)
