"""The parity check's measures: the largest differences from the float64 reference, the tolerances they allow,
and one ONNX Runtime run's differences.

A graph may be ``SLACK`` times further from float64 than PyTorch float32 is on the same frames and choices, and
is never held below the floors ``FLOOR_SCORE`` (scores) and ``FLOOR_BOX_M`` (boxes, m).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

__all__ = ["FLOOR_BOX_M", "FLOOR_SCORE", "SLACK", "Errors", "RunDiff"]

#: The smallest box tolerance (m) a graph is held to.
FLOOR_BOX_M = 1e-3
#: The smallest score tolerance a graph is held to.
FLOOR_SCORE = 1e-4
#: How much further from float64 than PyTorch float32 the graph may be.
SLACK = 4.0


@dataclass
class Errors:
    """Largest differences from the float64 reference (dense scores, boxes in m, scores)."""

    rank_score: float = 0.0
    box: float = 0.0
    score: float = 0.0

    def update(self, other: Errors) -> None:
        """Raise each measure to ``other``'s where that is larger.

        Args:
            other (Errors): differences of another run or frame.
        """
        self.rank_score = max(self.rank_score, other.rank_score)
        self.box = max(self.box, other.box)
        self.score = max(self.score, other.score)

    def tolerances(self) -> Errors:
        """What a graph may differ by, given that PyTorch float32 differs by ``self``."""
        return Errors(
            max(FLOOR_SCORE, SLACK * self.rank_score),
            max(FLOOR_BOX_M, SLACK * self.box),
            max(FLOOR_SCORE, SLACK * self.score),
        )


@dataclass
class RunDiff:
    """One ONNX Runtime run (a batch of frames) against the float64 reference."""

    errors: Errors = field(default_factory=Errors)
    boxes: list[np.ndarray] = field(default_factory=list)  # per frame: box difference per position
    scores: list[np.ndarray] = field(default_factory=list)
    selection_valid: bool = True  # the graph's choice is a top-k of its own dense scores
    own_selection: bool = True  # ... and it is PyTorch float32's own choice, position by position
    tie_swaps: int = 0  # positions whose index differs from PyTorch float32's choice
    tie_substitutions: int = 0  # chosen indices outside PyTorch float32's top K
    labels_equal: bool = True
    valid_equal: bool = True
    other_label_or_validity: int = 0  # boxes
    notes: list[str] = field(default_factory=list)

    def mismatched(self, tol: Errors) -> int:
        """Boxes beyond tolerance, or of another label or validity."""
        off = sum(int(np.count_nonzero((b > tol.box) | (s > tol.score))) for b, s in zip(self.boxes, self.scores))
        return off + self.other_label_or_validity

    def passed(self, tol: Errors) -> bool:
        """Whether the run is within ``tol`` (Errors): dense scores, a valid choice, no box beyond tolerance."""
        return self.errors.rank_score <= tol.rank_score and self.selection_valid and self.mismatched(tol) == 0
