"""Replaying a detector's ranking: the model's head run again from given dense scores and a given choice.

The parity check asks the float64 model what it answers at the graph's own choice; a ``RankingHead`` records
what the head received for each frame in one full run and replays the head alone, reusing what it computed
before its ranking step (``BeforeRanking``).
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
import torch
from torch import nn

from fisheye_infer.errors import ExportError
from fisheye_infer.models.ranking import TopK, replay_ranking

from .parity_runs import PROBE, Outputs, run_torch

__all__ = ["ExactAnswer", "RankingHead", "BeforeRanking", "ranking_head"]

@dataclass(frozen=True)
class ExactAnswer:
    """The float64 model's answer at a replayed ranking."""

    out: Outputs  # the float64 model's outputs at a replayed ranking
    own_dense: np.ndarray  # (M,) the float64 model's own dense scores
    problem: str  # "" when the replayed indices are a top-k of the replayed scores


class RankingHead:
    """A model's ranking head, with the inputs it received for each frame in one full run.

    The trunk runs once per frame; every replay of a ranking runs the head alone, and of the head only
    what follows the ranking (``BeforeRanking``): PETR's decoder, which comes before it, runs once.
    """

    def __init__(self, model: nn.Module, frames: np.ndarray, valid: np.ndarray) -> None:
        """Run ``model`` on each frame alone, recording its head's inputs and what it computed before ranking.

        Args:
            model (nn.Module): the detector, in the precision to replay.
            frames (np.ndarray): (F, N, H, W, 3) uint8 camera images.
            valid (np.ndarray): (F, N) bool, the cameras present in each frame.
        """
        self.module = ranking_head(model)
        self.inputs: list[tuple[tuple, dict]] = []
        self.before_ranking: list[BeforeRanking] = []
        hook = self.module.register_forward_pre_hook(
            lambda _, args, kwargs: self.inputs.append((args, kwargs)), with_kwargs=True
        )
        try:
            self.outputs = []
            for i in range(len(frames)):
                with BeforeRanking(self.module) as before:
                    self.outputs.append(run_torch(model, frames[i : i + 1], valid[i : i + 1]))
                self.before_ranking.append(before)
        finally:
            hook.remove()

    @torch.no_grad()
    def replay(self, frame: int, dense: np.ndarray, indices: np.ndarray) -> ExactAnswer:
        """The head's answer for ``frame`` when its ranking starts from ``dense`` and picks ``indices``.

        Args:
            frame (int): the frame, as recorded.
            dense (np.ndarray): (M,) the dense scores the ranking starts from.
            indices (np.ndarray): (K,) the indices it picks.

        Returns:
            ExactAnswer: the outputs, the head's own dense scores and what is wrong with the choice, if anything.

        Raises:
            ExportError: the replay produced no dense scores.
        """
        args, kwargs = self.inputs[frame]
        dtype = next(self.module.parameters()).dtype
        d = torch.from_numpy(np.ascontiguousarray(dense[None])).to(dtype)
        chosen = torch.from_numpy(np.ascontiguousarray(indices[None], np.int64))
        with replay_ranking(self.module, d, chosen) as step, self.before_ranking[frame].reused():
            out = self.module(*args, **kwargs)
        if step.own_dense is None:
            raise ExportError("the parity check's replay of the ranking produced no dense scores")
        return ExactAnswer({k: out[k].cpu().numpy() for k in PROBE}, step.own_dense.cpu().numpy()[0], step.problem)


class BeforeRanking:
    """What a ranking head computes before its ranking step, recorded in one run and handed back in replays.

    A replay changes the ranking's scores and choice only, so every submodule that returned before the
    ranking step first read its scores gives the same output again. Recorded: the outermost of those
    called once in the run (a module called several times keeps running); ``reused()`` makes each return
    a copy of its recorded output instead of running.
    """

    def __init__(self, head: nn.Module) -> None:
        """Record for ``head`` (nn.Module), which holds exactly one ranking step (``TopK``)."""
        self.head = head
        (self.step,) = [m for m in head.modules() if isinstance(m, TopK)]
        self.outputs: dict[str, object] = {}
        self.calls: dict[str, int] = {}
        self._ranked = False

    def __enter__(self) -> BeforeRanking:
        (step_name,) = [name for name, m in self.head.named_modules() if m is self.step]
        parts = step_name.split(".")
        owners = {".".join(parts[:i]) for i in range(len(parts) + 1)}  # the step and the modules that hold it
        self._hooks = [
            m.register_forward_hook(self._keep(name)) for name, m in self.head.named_modules() if name not in owners
        ]
        dense = self.step.dense

        def ranked(scores: torch.Tensor) -> torch.Tensor:
            self._ranked = True
            return dense(scores)

        self.step.dense = ranked  # type: ignore[method-assign]
        return self

    def __exit__(self, *exc: object) -> None:
        for hook in self._hooks:
            hook.remove()
        del self.step.dense  # the class's method again
        once = {name for name, count in self.calls.items() if count == 1 and name in self.outputs}
        outermost = {n for n in once if not any(n.startswith(f"{m}.") for m in once)}
        self.outputs = {n: v for n, v in self.outputs.items() if n in outermost}

    def _keep(self, name: str) -> Callable[[nn.Module, object, object], None]:
        def hook(module: nn.Module, args: object, output: object) -> None:
            self.calls[name] = self.calls.get(name, 0) + 1
            if not self._ranked:
                self.outputs[name] = _copy(output)  # as returned, whatever the run does with it afterwards

        return hook

    @contextlib.contextmanager
    def reused(self) -> Iterator[None]:
        """Within the block, each recorded module returns a copy of its recorded output instead of running."""
        modules = dict(self.head.named_modules())
        for name, output in self.outputs.items():
            modules[name].forward = lambda *_, _out=output, **__: _copy(_out)
        try:
            yield
        finally:
            for name in self.outputs:
                del modules[name].forward


def _copy(value: object) -> object:
    """Tensors cloned (a replay may write into what a module returns), containers rebuilt, the rest as is."""
    if isinstance(value, torch.Tensor):
        return value.clone()
    if isinstance(value, tuple) and hasattr(value, "_fields"):  # a named tuple
        named: Any = type(value)
        return named(*[_copy(v) for v in value])
    if isinstance(value, (tuple, list)):
        return type(value)([_copy(v) for v in value])
    if isinstance(value, dict):
        return {k: _copy(v) for k, v in value.items()}
    return value


def ranking_head(model: nn.Module) -> nn.Module:
    """The child of ``model`` that holds its ranking step and returns the detector's outputs.

    Args:
        model (nn.Module): the detector.

    Returns:
        nn.Module: its ranking head.

    Raises:
        ValueError: no child holds a ranking step.
    """
    for _, child in model.named_children():
        if any(isinstance(m, TopK) for m in child.modules()):
            return child
    raise ValueError(f"{type(model).__name__} has no ranking step")
