"""The one ranking step of each detector, and a way to replay another runtime's ranking in PyTorch.

Both heads choose what they return with a single top-k over dense scores: TransFusion over its
sigmoid heatmap after local-max suppression (every class and BEV cell), PETR over the sigmoid
scores of every query and class. The discrete steps are not continuous in their input: among
exactly equal scores top-k's choice is not defined (PyTorch and ONNX Runtime break such ties
differently, and with trained-like weights and frames with uniform regions whole runs of cells
tie), and a last-bit difference decides whether a cell survives local-max suppression next to an
equal neighbour. In TransFusion the chosen proposals also attend to each other, so one
substitution moves every box a little.

So the export check compares what is defined: the dense scores *before* any discrete step,
within tolerance; then, inside ``replay_ranking(model, dense, indices)``, PyTorch runs the
discrete steps on the graph's own dense scores, confirms that the graph's indices are a top-k of
them, and continues from the graph's choice, so every box can be compared position by position.
The heads expose their ranking as two extra outputs, ``rank_scores`` (B, M), the dense scores
before suppression, and ``rank_indices`` (B, K); only the checked graph keeps them.
"""

from __future__ import annotations

import contextlib
from collections.abc import Iterator

import torch
from torch import nn

from fisheye_infer.runtime.artifact import RANKING_OUTPUTS

__all__ = ["RANKING_OUTPUTS", "TopK", "replay_ranking"]


class TopK(nn.Module):
    """``torch.topk(scores, k, dim=1)`` (sorted, largest first), or the ranking being replayed.

    The head passes its dense scores through `dense` before any discrete step and its
    final scores through ``forward``; outside a replay both are plain.
    """

    def __init__(self, k: int) -> None:
        super().__init__()
        self.k = int(k)
        self.replay: tuple[torch.Tensor, torch.Tensor] | None = None
        self.problem = ""  # why the replayed indices are not a top-k ("" when they are)
        self.own_dense: torch.Tensor | None = None  # during a replay: the head's own dense scores

    def dense(self, scores: torch.Tensor) -> torch.Tensor:
        """The dense scores the discrete steps start from: the head's own, or the replayed ones."""
        if self.replay is None:
            return scores
        self.own_dense = scores
        dense = self.replay[0]
        if dense.numel() != scores.numel():
            raise ValueError(f"replayed scores: expected {tuple(scores.shape)} values, got {tuple(dense.shape)}")
        return dense.reshape(scores.shape).to(scores.dtype)

    def forward(self, scores: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        # scores: B x M -> values B x K, indices B x K (int64)
        if self.replay is None:
            return torch.topk(scores, self.k, dim=1, largest=True, sorted=True)
        indices = self.replay[1]
        if tuple(indices.shape) != (scores.shape[0], self.k):
            raise ValueError(f"replayed indices: expected ({scores.shape[0]}, {self.k}), got {tuple(indices.shape)}")
        self.problem = _not_a_top_k(scores, indices)
        safe = indices.clamp(0, scores.shape[1] - 1)  # out-of-range indices are reported, not gathered
        return scores.gather(1, safe), indices


def _not_a_top_k(scores: torch.Tensor, indices: torch.Tensor) -> str:
    """ "" if ``indices`` (B, K) are a top-k of ``scores`` (B, M) in descending order, else why not.

    Exact comparisons: the replay runs on the very scores the indices were chosen from.
    """
    if int(indices.min()) < 0 or int(indices.max()) >= scores.shape[1]:
        return "an index is out of range"
    if any(len(torch.unique(row)) != len(row) for row in indices):
        return "an index is chosen twice"
    chosen = scores.gather(1, indices)
    left = scores.scatter(1, indices, float("-inf"))
    if bool((left.max(dim=1).values > chosen.min(dim=1).values).any()):
        return "a score left out beats a chosen one"
    if bool((chosen[:, 1:] > chosen[:, :-1]).any()):
        return "the chosen scores are not in descending order"
    return ""


@contextlib.contextmanager
def replay_ranking(model: nn.Module, dense: torch.Tensor, indices: torch.Tensor) -> Iterator[TopK]:
    """Inside the block ``model``'s ranking step starts from ``dense`` (B, M) and chooses ``indices``
    (B, K); the step is yielded: afterwards its ``problem`` says whether that was a top-k, and
    ``own_dense`` holds the dense scores the model computed itself."""
    steps = [m for m in model.modules() if isinstance(m, TopK)]
    if len(steps) != 1:
        raise ValueError(f"{type(model).__name__} has {len(steps)} ranking steps; a replay needs exactly one")
    step = steps[0]
    step.replay, step.problem, step.own_dense = (dense, indices.to(torch.int64)), "", None
    try:
        yield step
    finally:
        step.replay = None
