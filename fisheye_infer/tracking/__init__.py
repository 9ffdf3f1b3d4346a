"""Tracks over a stream of detections: ``Tracker`` (Kalman filters, optimal two-stage association) and
``GreedyTracker`` (CenterPoint's greedy matching, the baseline), both returning ``Tracks``.

    from fisheye_infer import Detector, Tracker

    detector, tracker = Detector("model.onnx"), Tracker()
    for images, stamp, pose in stream:
        tracks = tracker.update(detector.detect(images), stamp, ego_pose=pose)

``smooth_velocities`` re-fits a finished sequence's velocities from the frames either side (results files).
"""

from fisheye_infer.tracking.config import DEFAULT_CLASSES, TURNING_CLASSES, ClassConfig, TrackerConfig
from fisheye_infer.tracking.greedy import GreedyTracker
from fisheye_infer.tracking.motion import ConstantTurnRate, ConstantVelocity, MotionModel
from fisheye_infer.tracking.smoothing import smooth_velocities
from fisheye_infer.tracking.tracker import Tracker
from fisheye_infer.tracking.tracks import Tracks

__all__ = [
    "DEFAULT_CLASSES",
    "TURNING_CLASSES",
    "ClassConfig",
    "ConstantTurnRate",
    "ConstantVelocity",
    "GreedyTracker",
    "MotionModel",
    "Tracker",
    "TrackerConfig",
    "Tracks",
    "smooth_velocities",
]
