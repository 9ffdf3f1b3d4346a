"""The ranking step and its replay, on hand-made scores."""

from __future__ import annotations

import pytest
import torch
from torch import nn

from fisheye_infer.models.ranking import TopK, replay_ranking


class _Head(nn.Module):
    """dense scores -> (top-k values, indices), as a detector head uses its ranking step."""

    def __init__(self, k: int) -> None:
        super().__init__()
        self.select = TopK(k)

    def forward(self, scores: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        dense = self.select.dense(scores)
        values, indices = self.select(dense * 2.0)  # a discrete step after some arithmetic
        return dense, values, indices


SCORES = torch.tensor([[0.9, 0.5, 0.5, 0.1, 0.5]])


def test_plain_top_k_outside_a_replay() -> None:
    dense, values, indices = _Head(2)(SCORES)
    assert torch.equal(dense, SCORES) and indices[0, 0] == 0 and values[0, 1] == 1.0


@pytest.mark.parametrize(
    ("indices", "problem"),
    [
        ([0, 2, 1], ""),  # ties at 0.5 broken otherwise: a top-k all the same
        ([0, 4, 2], ""),
        ([0, 3, 1], "a score left out beats a chosen one"),
        ([1, 0, 2], "not in descending order"),
        ([0, 1, 1], "chosen twice"),
        ([0, 1, 7], "out of range"),
    ],
)
def test_replay_judges_the_indices_on_the_replayed_scores(indices: list[int], problem: str) -> None:
    head = _Head(3)
    own = torch.zeros_like(SCORES)  # the head's own scores would rank otherwise
    with replay_ranking(head, SCORES, torch.tensor([indices])) as step:
        dense, values, got = head(own)
    assert step.problem.endswith(problem) if problem else step.problem == ""
    assert torch.equal(dense, SCORES) and got.tolist() == [indices] and step.own_dense is not None
    assert torch.equal(step.own_dense, own)
    if not problem:
        assert torch.equal(values, (SCORES * 2.0).gather(1, got))
    assert head.select.replay is None  # the replay ends with the block


def test_replay_refuses_the_wrong_shapes() -> None:
    head = _Head(3)
    with replay_ranking(head, SCORES, torch.tensor([[0, 1]])), pytest.raises(ValueError, match=r"expected \(1, 3\)"):
        head(SCORES)
    with (
        replay_ranking(head, torch.zeros(1, 4), torch.tensor([[0, 1, 2]])),
        pytest.raises(ValueError, match="replayed scores"),
    ):
        head(SCORES)
    with pytest.raises(ValueError, match="exactly one"), replay_ranking(nn.Linear(2, 2), SCORES, torch.tensor([[0]])):
        pass
