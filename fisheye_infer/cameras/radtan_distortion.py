"""OpenCV's radial-tangential lens distortion of normalised image coordinates, and its inverse."""

from __future__ import annotations

import cv2
import numpy as np

__all__ = ["radtan_distort", "radtan_undistort"]


def radtan_distort(x: np.ndarray, y: np.ndarray, d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """OpenCV's distortion of normalised coordinates: radial k1, k2[, k3] (rational k4, k5, k6 divide),
    tangential p1, p2; ``d`` in OpenCV's order (k1, k2, p1, p2[, k3[, k4, k5, k6]])."""
    k1, k2, p1, p2, k3, k4, k5, k6 = (*d, 0.0, 0.0, 0.0, 0.0)[:8]
    r2 = x * x + y * y
    radial = (1 + r2 * (k1 + r2 * (k2 + r2 * k3))) / (1 + r2 * (k4 + r2 * (k5 + r2 * k6)))
    return (
        x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
        y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y,
    )


def radtan_undistort(x: np.ndarray, y: np.ndarray, d: tuple[float, ...]) -> tuple[np.ndarray, np.ndarray]:
    """Invert ``radtan_distort`` with OpenCV's iterative undistortion (identity camera matrix, 100 iterations)."""
    if not any(d):
        return x, y
    pts = np.stack([x, y], axis=-1).reshape(-1, 1, 2)
    criteria = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 100, 1e-12)
    coeffs = np.asarray(d, np.float64)
    if hasattr(cv2, "undistortPointsIter"):  # OpenCV 4's name for the overload with a criteria
        out = cv2.undistortPointsIter(pts, np.eye(3), coeffs, None, None, criteria)
    else:
        out = cv2.undistortPoints(pts, np.eye(3), coeffs, criteria=criteria)
    out = out.reshape(-1, 2)
    return out[:, 0], out[:, 1]
