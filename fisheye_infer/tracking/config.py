"""Per-class tracking settings: the motion model, its noise, and the association gate.

    TrackerConfig()                                   # the defaults below, by class name
    TrackerConfig(classes={"Car": ClassConfig(ConstantTurnRate(position_std=0.3), gate=1.5)})

Every class moves with a constant velocity by default, pedestrians with less process and
measurement noise than vehicles and cyclists; ``TURNING_CLASSES`` puts the vehicles on the
constant-turn-rate model (CTRV), as Poly-MOT assigns its models, which pays where the detector's yaw
is reliable (see the Tracking guide for the figures of both). A class the table does not name gets
``default``. A detection and a predicted track pair only within the class's ``gate`` (metres,
bird's-eye-view centre distance) plus twice the predicted centre's standard deviation, so a
young or coasting track, whose position is less certain, reaches further. The gates (3 m for cars
and vans, 4 m for trucks and buses, 2 m for pedestrians, 2.5 m for cyclists) cover camera detectors'
centre errors, which grow with range to metres beyond 30 m; a gate tighter than that splits an
object's track wherever its detection strays. Vehicles park, so a vehicle track whose velocity cannot
be told from zero at 95 % confidence is reported standing still (``parked_level``); pedestrians and
cyclists move at speeds close to their velocity's uncertainty, so the test would stop moving ones,
and their velocity is reported as the filter has it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field

from fisheye_infer.errors import OptionError
from fisheye_infer.tracking.motion import ConstantTurnRate, ConstantVelocity, MotionModel

__all__ = ["ClassConfig", "TrackerConfig", "DEFAULT_CLASSES", "TURNING_CLASSES"]


@dataclass(frozen=True)
class ClassConfig:
    """How one class is tracked: its motion model and association gate.

    Args:
        model (MotionModel): The motion model and its noise
            ([`ConstantVelocity`][fisheye_infer.tracking.motion.ConstantVelocity] or
            [`ConstantTurnRate`][fisheye_infer.tracking.motion.ConstantTurnRate]).
        gate (float): Association gate, metres of bird's-eye-view centre distance; a pair is allowed within
            the gate plus twice the predicted centre's standard deviation.
        parked_level (float): A track whose velocity cannot be told from zero at this confidence level (its
            estimate's confidence region holds zero) is reported standing still, velocity 0; 0 reports the
            filter's velocity as is.
    """

    model: MotionModel
    gate: float = 2.0
    parked_level: float = 0.0


_MOVER = ConstantVelocity(position_std=0.7, accel_std=3.0, speed_std=8.0)
_PARKED = 0.95
#: The settings per class name.
DEFAULT_CLASSES: dict[str, ClassConfig] = {
    "Car": ClassConfig(_MOVER, 3.0, _PARKED),
    "Van": ClassConfig(_MOVER, 3.0, _PARKED),
    "Truck": ClassConfig(_MOVER, 4.0, _PARKED),
    "Bus": ClassConfig(_MOVER, 4.0, _PARKED),
    "Pedestrian": ClassConfig(ConstantVelocity(position_std=0.5, accel_std=1.5, speed_std=2.0), 2.0),
    "Cyclist": ClassConfig(_MOVER, 2.5),
}
#: Vehicles on the constant-turn-rate model, for detectors whose yaw is good to about 0.2 rad (``TrackerConfig(
#: classes=TURNING_CLASSES)``); with a yaw that is often wrong the heading misleads the filter and the
#: constant-velocity defaults track better.
TURNING_CLASSES: dict[str, ClassConfig] = {
    **DEFAULT_CLASSES,
    **{
        name: ClassConfig(ConstantTurnRate(position_std=0.4, accel_std=2.5, speed_std=8.0, yaw_std=0.2), gate, _PARKED)
        for name, gate in (("Car", 3.0), ("Van", 3.0), ("Truck", 4.0), ("Bus", 4.0))
    },
}


@dataclass(frozen=True)
class TrackerConfig:
    """Settings of a [`Tracker`][fisheye_infer.tracking.tracker.Tracker]; every value is checked on construction.

    Args:
        score_threshold (float): Detections at or above it start tracks and are associated first.
        low_score (float): Detections in [low_score, score_threshold) only keep confirmed tracks alive
            (the second association stage); below it they are ignored.
        min_hits (int): Matches that confirm a track; tracks are reported from then on.
        max_coast (float): Seconds a confirmed track survives unmatched (frames with a camera
            missing do not count), predicted by its motion model.
        max_tracks (int): Cap on live tracks; past it the least certain are dropped.
        size_smoothing (float): Weight of a new detection in the track's height and size, (0, 1].
        birth_clearance (float): A confident detection starts no track within this many metres of a live track of
            its class or of a better detection starting one (duplicates of one object start one track).
        young_weight (float): A track's reported score is its detection's times ``1 - young_weight ** hits``, so
            tracks seen once or twice (often false alarms) rank below established ones; 0 reports the score as is.
        classes (Mapping[str, ClassConfig]): Settings per class name.
        default (ClassConfig): Settings of a class the table does not name.

    Raises:
        OptionError: A value is out of range, or a class's gate is not a positive number of metres or its
            ``parked_level`` not in [0, 1).
    """

    score_threshold: float = 0.3
    low_score: float = 0.1
    min_hits: int = 1
    max_coast: float = 1.0
    max_tracks: int = 500
    size_smoothing: float = 0.3
    birth_clearance: float = 2.0
    young_weight: float = 0.5
    classes: Mapping[str, ClassConfig] = field(default_factory=lambda: dict(DEFAULT_CLASSES))
    default: ClassConfig = ClassConfig(ConstantVelocity(position_std=0.5, accel_std=2.0, speed_std=5.0), 3.0)

    def __post_init__(self) -> None:
        checks = (
            ("score_threshold", 0 <= self.score_threshold <= 1, "in [0, 1]"),
            ("low_score", 0 <= self.low_score <= self.score_threshold, "in [0, score_threshold]"),
            ("min_hits", isinstance(self.min_hits, int) and self.min_hits >= 1, "an integer >= 1"),
            ("max_coast", math.isfinite(self.max_coast) and self.max_coast >= 0, "a finite number >= 0 (seconds)"),
            ("max_tracks", isinstance(self.max_tracks, int) and self.max_tracks >= 1, "an integer >= 1"),
            ("size_smoothing", 0 < self.size_smoothing <= 1, "in (0, 1]"),
            ("birth_clearance", math.isfinite(self.birth_clearance) and self.birth_clearance >= 0, "a number >= 0 (m)"),
            ("young_weight", 0 <= self.young_weight < 1, "in [0, 1)"),
        )
        for name, ok, expected in checks:
            if not ok:
                raise OptionError(f"tracker {name}: expected {expected}, got {getattr(self, name)!r}")
        for name, cc in {**self.classes, "default": self.default}.items():
            if not (math.isfinite(cc.gate) and cc.gate > 0):
                raise OptionError(f"tracker class {name!r}: gate must be a positive number of metres, got {cc.gate!r}")
            if not 0 <= cc.parked_level < 1:
                raise OptionError(f"tracker class {name!r}: parked_level must be in [0, 1), got {cc.parked_level!r}")

    def for_class(self, name: str) -> ClassConfig:
        """The settings of one class.

        Args:
            name (str): A class name.

        Returns:
            ClassConfig: ``classes[name]``, or ``default`` for a class the table does not name.
        """
        return self.classes.get(name, self.default)
