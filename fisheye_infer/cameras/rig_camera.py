"""One camera of a rig: its name, its camera model and its pose in the lidar frame.

The lidar frame is x forward, y left, z up (metres); the camera frame is OpenCV's (x right, y down,
z forward). ``cam2lidar`` maps camera-frame points into the lidar frame and must be rigid.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from fisheye_infer.cameras.camera_models import AnyCameraModel

__all__ = ["RigCamera"]

_RIGID_TOLERANCE = 1e-4


class RigCamera(BaseModel):
    """One camera of a rig: its name, lens and pose.

    Attributes:
        name (str): The camera's name (non-empty, unique in its rig).
        model (AnyCameraModel): Its camera model, one of the models above, told apart by ``type``.
        cam2lidar (tuple[tuple[float, float, float, float], ...]): 4x4 rigid transform from the camera
            (OpenCV) frame to the lidar frame, metres; the last row is (0, 0, 0, 1).

    Raises:
        pydantic.ValidationError: ``cam2lidar`` not 4x4, not finite or not rigid (within 1e-4), or an invalid
            model.

    Examples:
        ```python
        from fisheye_infer.cameras.rig import default_rig

        front = default_rig().camera("fisheye_camera_front")
        front.model.type, front.position, front.heading   # "ocam", (3,) metres, radians (0 = forward)
        ```
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    name: str = Field(min_length=1)
    model: AnyCameraModel
    cam2lidar: tuple[tuple[float, float, float, float], ...] = Field(description="4x4, camera (OpenCV) to lidar frame")

    @field_validator("cam2lidar")
    @classmethod
    def _rigid(cls, value: tuple[tuple[float, ...], ...]) -> tuple[tuple[float, ...], ...]:
        m = np.asarray(value, dtype=np.float64)
        if m.shape != (4, 4):
            raise ValueError(f"must be 4x4, got {len(value)} rows")
        if not np.all(np.isfinite(m)):
            raise ValueError("contains NaN or infinity")
        if not np.allclose(m[3], (0, 0, 0, 1), atol=1e-9):
            raise ValueError(f"last row must be [0, 0, 0, 1], got {m[3].tolist()}")
        rot = m[:3, :3]
        err = np.abs(rot.T @ rot - np.eye(3)).max()
        if err > _RIGID_TOLERANCE or np.linalg.det(rot) < 0:
            raise ValueError(f"rotation is not rigid (|R^T R - I| = {err:.2e}, det = {np.linalg.det(rot):.4f})")
        return value

    @property
    def matrix(self) -> np.ndarray:
        """cam2lidar as a (4, 4) float64 array."""
        return np.asarray(self.cam2lidar, dtype=np.float64)

    @property
    def position(self) -> np.ndarray:
        """Camera centre in the lidar frame (m)."""
        return self.matrix[:3, 3]

    @property
    def heading(self) -> float:
        """Azimuth of the optical axis in the lidar x-y plane, radians (0 = forward, +pi/2 = left)."""
        axis = self.matrix[:3, 2]
        return math.atan2(axis[1], axis[0])
