"""How sure a difference between two scores on the same held-out frames is: a paired bootstrap over frames.

    draws = frame_draws(len(gt_a.tokens), 200)            # one set of resamples for every model compared
    a = resampled_fds(gt_a, pred_a, draws)                 # (200,) FDS of model A on each resample
    b = resampled_fds(gt_b, pred_b, draws)
    low, high = interval(a - b)                            # 90% percentile interval of A - B

Two models scored on the same frames share each frame's difficulty, so their difference varies far
less than either score: the resamples must draw the same frames for both (``frame_draws`` once, and
boxes whose ``tokens`` index the same scenes in the same order). A difference whose interval holds 0
is not resolved by those frames.
"""

from __future__ import annotations

import numpy as np

from fisheye_infer.eval.eval_boxes import EvalBoxes
from fisheye_infer.eval.evaluate import summarise
from fisheye_infer.eval.metric_config import EvalConfig

__all__ = ["frame_draws", "resampled_fds", "interval", "resolved"]


def frame_draws(frames: int, draws: int, seed: int = 0) -> np.ndarray:
    """Frame indices drawn with replacement: the resamples every compared score is taken on.

    Args:
        frames (int): Frames scored (``len(gt.tokens)``).
        draws (int): Resamples.
        seed (int): Seed of the draws; the same seed gives the same resamples.

    Returns:
        np.ndarray: `(draws, frames)` int indices into the frames.

    Raises:
        ValueError: ``frames`` or ``draws`` is below 1.
    """
    if frames < 1 or draws < 1:
        raise ValueError(f"frames and draws: expected at least 1 each, got {frames} and {draws}")
    return np.random.default_rng(seed).integers(0, frames, size=(draws, frames))


def resampled_fds(
    gt: EvalBoxes, pred: EvalBoxes, draws: np.ndarray, config: EvalConfig | None = None, ref_range: float | None = None
) -> np.ndarray:
    """The FDS on each resample of frames.

    Args:
        gt (EvalBoxes): Ground-truth boxes.
        pred (EvalBoxes): Predicted boxes on the same sample tokens, in the same order.
        draws (np.ndarray): `(D, F)` resamples from [`frame_draws`][fisheye_infer.eval.bootstrap.frame_draws];
            use the same draws for every model compared.
        config (EvalConfig | None): The metric's settings (default: ``EvalConfig()``).
        ref_range (float | None): Rescale the classes' ranges to this reference range, metres, as in the
            report's distance breakdown (default: as configured).

    Returns:
        np.ndarray: `(D,)` FDS per resample.

    Raises:
        ValueError: ``gt`` and ``pred`` do not share their sample tokens in the same order.

    Examples:
        ```python
        draws = frame_draws(len(gt_a.tokens), 200)
        a = resampled_fds(gt_a, pred_a, draws)
        b = resampled_fds(gt_b, pred_b, draws)
        low, high = interval(a - b)            # 90% interval of FDS(A) - FDS(B)
        print(low, high, resolved(low, high))
        ```
    """
    if gt.tokens != pred.tokens:
        raise ValueError("gt/pred: the two box sets must share their sample tokens, in the same order")
    config = config or EvalConfig()
    return np.array([summarise(gt.take(d), pred.take(d), config, ref_range).FDS for d in draws])


def interval(values: np.ndarray, level: float = 0.9) -> tuple[float, float]:
    """The central percentile interval of resampled values.

    Args:
        values (np.ndarray): Resampled values (e.g. a difference of two models' FDS per resample).
        level (float): Share of the values the interval holds, in (0, 1).

    Returns:
        tuple[float, float]: The interval's low and high ends.

    Raises:
        ValueError: ``level`` is outside (0, 1).
    """
    if not 0 < level < 1:
        raise ValueError(f"level: expected a share in (0, 1), got {level}")
    tail = 50 * (1 - level)
    low, high = np.percentile(np.asarray(values, np.float64), [tail, 100 - tail])
    return float(low), float(high)


def resolved(low: float, high: float) -> bool:
    """Whether an interval of a difference excludes 0: the frames tell which side is larger.

    Args:
        low (float): The interval's low end.
        high (float): The interval's high end.

    Returns:
        bool: True where 0 lies outside [low, high].
    """
    return low > 0 or high < 0
