"""The focal losses on hand-made predictions."""

from __future__ import annotations

import pytest

torch = pytest.importorskip("torch")

from fisheye_infer.models.training.losses import gaussian_focal_loss, sigmoid_focal_loss  # noqa: E402


def test_gaussian_focal_loss_rewards_the_target_shape() -> None:
    target = torch.tensor([[0.0, 0.5, 1.0, 0.5, 0.0]])
    good = torch.logit(target.clamp(1e-4, 1 - 1e-4))
    assert gaussian_focal_loss(good, target) < 0.05  # only the 0.5 cells cost: 2 x log(2) x 0.5^2 x 0.5^4
    assert gaussian_focal_loss(torch.full_like(target, -2.19), target) > 0.5
    # cells near a peak are hardly penalised for being high: (1 - target)^4 weights the negative term
    near = gaussian_focal_loss(torch.tensor([[0.0]]), torch.tensor([[0.9]]))
    far = gaussian_focal_loss(torch.tensor([[0.0]]), torch.tensor([[0.0]]))
    assert near < far / 1000


def test_sigmoid_focal_loss_treats_label_k_as_background() -> None:
    logits = torch.tensor([[-6.0, -6.0, -6.0], [6.0, -6.0, -6.0]])
    assert sigmoid_focal_loss(logits, torch.tensor([3, 0])) < 1e-3  # both right: nothing, and class 0
    assert sigmoid_focal_loss(logits, torch.tensor([1, 3])) > 1.0
