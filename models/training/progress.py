"""The training loop's progress line: step, bar, smoothed loss terms, seconds per step and time left."""

from __future__ import annotations

import sys
from collections.abc import Callable

__all__ = ["ProgressBar", "loss_terms"]


class ProgressBar:
    """One redrawn status line: step, bar, smoothed loss terms, seconds per step and time left."""

    WIDTH = 24

    def __init__(self, total: int, done: int, terms: tuple[str, ...], write: Callable[[str], None] | None) -> None:
        """A line for a run of ``total`` steps.

        Args:
            total (int): the run's last step.
            done (int): the step it starts from.
            terms (tuple[str, ...]): the loss terms shown, ``loss`` among them.
            write (Callable[[str], None] | None): where the text goes (default: standard error).
        """
        self.total, self.done, self.terms = total, done, terms
        self.mean: dict[str, float] = {}
        self.write = write or (lambda text: (sys.stderr.write(text), sys.stderr.flush()))
        self.seconds: float | None = None

    def update(self, row: dict[str, float]) -> None:
        """Redraw the line for a step's log row (its ``step``, ``seconds`` and loss terms).

        Args:
            row (dict[str, float]): the step's log row.
        """
        self.done = int(row["step"])
        for k in self.terms:
            self.mean[k] = row[k] if k not in self.mean else 0.9 * self.mean[k] + 0.1 * row[k]
        self.seconds = row["seconds"] if self.seconds is None else 0.9 * self.seconds + 0.1 * row["seconds"]
        filled = int(self.WIDTH * self.done / self.total)
        left = (self.total - self.done) * self.seconds
        bar = f"[{'#' * filled}{'.' * (self.WIDTH - filled)}]"
        self.write(
            f"\r{self.done}/{self.total} {bar} {loss_terms(self.mean, self.terms)} "
            f"{self.seconds:.1f} s/step, {left / 60:.0f} min left "
        )

    def note(self, text: str) -> None:
        """Write ``text`` on a line of its own below the bar.

        Args:
            text (str): the note.
        """
        self.write(f"\n{text}\n")

    def close(self) -> None:
        """End the line."""
        self.write("\n")


def loss_terms(values: dict[str, float], names: tuple[str, ...]) -> str:
    """``loss 1.234 (cls 0.5 bbox 0.7 ...)``: the loss and its terms, short names.

    Args:
        values (dict[str, float]): the terms' values by name, ``loss`` among them.
        names (tuple[str, ...]): the terms to show, in order.

    Returns:
        str: the text.
    """
    parts = [f"{n.removeprefix('loss_')} {values[n]:.3f}" for n in names if n != "loss"]
    return f"loss {values['loss']:.3f} ({' '.join(parts)})"
