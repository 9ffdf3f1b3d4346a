"""The channels-last normalisation gives the channels-first formula's numbers exactly."""

from __future__ import annotations

import pytest
import torch

from fisheye_infer.models.normalise import normalise_frames

MEAN = torch.tensor([123.675, 116.28, 103.53])
STD = torch.tensor([58.395, 57.12, 57.375])


@pytest.mark.parametrize("bgr_to_rgb", [False, True])
def test_equals_the_channels_first_formula(bgr_to_rgb: bool) -> None:
    images = torch.randint(0, 256, (2, 4, 5, 7, 3), dtype=torch.uint8, generator=torch.Generator().manual_seed(0))
    x = images.to(torch.float32).flatten(0, 1).permute(0, 3, 1, 2)
    if bgr_to_rgb:
        x = x[:, [2, 1, 0]]
    expected = (x - MEAN.reshape(1, 3, 1, 1)) / STD.reshape(1, 3, 1, 1)
    out = normalise_frames(images, MEAN, STD, bgr_to_rgb)
    assert out.shape == (8, 3, 5, 7)
    assert torch.equal(out, expected)


def test_rows_of_one_frame_do_not_mix() -> None:
    """A pixel's three values come out at its own position, channels in order."""
    images = torch.zeros(1, 1, 2, 3, 3, dtype=torch.uint8)
    images[0, 0, 1, 2] = torch.tensor([200, 100, 50], dtype=torch.uint8)
    out = normalise_frames(images, MEAN, torch.ones(3))
    torch.testing.assert_close(out[0, :, 1, 2], torch.tensor([200.0, 100.0, 50.0]) - MEAN)
    torch.testing.assert_close(out[0, :, 0, 0], -MEAN)
