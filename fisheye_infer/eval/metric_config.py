"""The FDS/mAP metric's settings: ``EvalConfig``, whose defaults are the official evaluator's.

The defaults are the official Fisheye3DOD evaluator's (a nuScenes ``DetectionEval`` with its own
classes, ranges and weights): classes Car, Van, Truck, Bus, Pedestrian, Cyclist; x-y ranges
48/48/48/48/36/42 m (scaled by ``ref_range / 48`` when a reference range is given); centre
distance thresholds 0.5/1/2/4 m; TP errors at 2 m; min recall and min precision 0.1;
FDS = (3 mAP + sum over ATE, ASE, AOE of (1 - min(1, mTP))) / 6. Orientation errors use a 2 pi
period for every class, and no per-sample box cap is applied, as in the official code.

    config = EvalConfig()                               # the official settings
    config = EvalConfig.load("eval.json")               # or a JSON file with any subset of fields
    EvalConfig.deserialize(config.serialize()) == config
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from fisheye_infer.errors import ConfigError
from fisheye_infer.runtime.records import CLASSES

__all__ = ["EvalConfig", "REFERENCE_RANGE"]

#: The range the class ranges are stated for; ``ref_range`` rescales them relative to it.
REFERENCE_RANGE = 48.0


class EvalConfig(BaseModel):
    """Settings of the FDS/mAP metric; the defaults reproduce the official evaluator.

    Attributes:
        class_names (tuple[str, ...]): The classes scored, in label order.
        class_range (dict[str, float]): x-y range per class, metres, stated for a 48 m reference range; boxes
            beyond it are dropped from ground truth and predictions alike.
        ref_range (float | None): Rescale every class range by ``ref_range / 48`` (the paper's 0-30 m is 30;
            None: as stated).
        dist_ths (tuple[float, ...]): Centre-distance thresholds (m) whose APs are averaged.
        dist_th_tp (float): The threshold whose matches give the TP errors (m); one of ``dist_ths``.
        min_recall (float): Recall below which the precision curve is ignored, in [0, 1].
        min_precision (float): Precision below which the curve is ignored, in [0, 1).
        mean_ap_weight (float): Weight of mAP in FDS.
        orientation_period (dict[str, float]): Yaw period per class, radians (classes not named: 2 pi).
        max_boxes_per_sample (int | None): Keep only this many top-scoring predictions per sample
            (None: all, as officially).
        distance_breakdown (tuple[float, ...]): Reference ranges (m) the report repeats the metric at.

    Raises:
        pydantic.ValidationError: A value is out of range, the ranges do not name exactly the classes, or
            ``dist_th_tp`` is not one of ``dist_ths``.
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    class_names: tuple[str, ...] = Field(default=CLASSES, min_length=1)
    class_range: dict[str, float] = Field(
        default_factory=lambda: {
            "Car": 48.0,
            "Van": 48.0,
            "Truck": 48.0,
            "Bus": 48.0,
            "Pedestrian": 36.0,
            "Cyclist": 42.0,
        },
        description="x-y range per class (m), stated for a 48 m reference range",
    )
    ref_range: float | None = Field(
        default=None, gt=0, description="rescale every class range by ref_range / 48 (the paper's 0-30 m is 30)"
    )
    dist_ths: tuple[float, ...] = Field(
        default=(0.5, 1.0, 2.0, 4.0), min_length=1, description="centre-distance thresholds (m) averaged into AP"
    )
    dist_th_tp: float = Field(default=2.0, description="threshold whose matches give the TP errors (m)")
    min_recall: float = Field(default=0.1, ge=0, le=1)
    min_precision: float = Field(default=0.1, ge=0, lt=1)
    mean_ap_weight: float = Field(default=3.0, ge=0, description="weight of mAP in FDS")
    orientation_period: dict[str, float] = Field(
        default_factory=dict,
        description="yaw period per class (rad); classes not named use 2 pi, as the official metric does for all",
    )
    max_boxes_per_sample: int | None = Field(
        default=None, ge=1, description="keep only the top-scoring boxes per sample (not applied officially)"
    )
    distance_breakdown: tuple[float, ...] = Field(
        default=(30.0, 48.0), description="reference ranges of the distance breakdown (0-r m)"
    )

    @model_validator(mode="after")
    def _consistent(self) -> EvalConfig:
        if len(set(self.class_names)) != len(self.class_names):
            raise ValueError(f"class_names: repeated names in {list(self.class_names)}")
        missing = [c for c in self.class_names if c not in self.class_range]
        extra = [c for c in self.class_range if c not in self.class_names]
        if missing or extra:
            raise ValueError(f"class_range: must name exactly the classes; missing {missing}, unknown {extra}")
        bad = {c: r for c, r in self.class_range.items() if not (r > 0 and math.isfinite(r))}
        if bad:
            raise ValueError(f"class_range: ranges must be positive and finite, got {bad}")
        unknown = [c for c in self.orientation_period if c not in self.class_names]
        if unknown or any(not p > 0 for p in self.orientation_period.values()):
            raise ValueError(
                f"orientation_period: expects positive periods of known classes, got {self.orientation_period}"
            )
        if any(not t > 0 for t in self.dist_ths) or self.dist_th_tp not in self.dist_ths:
            raise ValueError(
                f"dist_ths/dist_th_tp: thresholds must be positive and include dist_th_tp={self.dist_th_tp}, "
                f"got {list(self.dist_ths)}"
            )
        if any(not r > 0 for r in self.distance_breakdown):
            raise ValueError(
                f"distance_breakdown: reference ranges must be positive, got {list(self.distance_breakdown)}"
            )
        return self

    # -- derived values ----------------------------------------------------------------------

    def class_ranges(self, ref_range: float | None = None) -> np.ndarray:
        """The range of each class, rescaled to a reference range.

        Args:
            ref_range (float | None): Reference range, metres (default: this config's ``ref_range``).

        Returns:
            np.ndarray: `(C,)` range per class id, metres.
        """
        ref = self.ref_range if ref_range is None else ref_range
        scale = 1.0 if ref is None else ref / REFERENCE_RANGE
        return np.array([self.class_range[c] * scale for c in self.class_names])

    def period(self, class_name: str) -> float:
        """The yaw period of a class.

        Args:
            class_name (str): A class name.

        Returns:
            float: Its period in ``orientation_period``, else 2 pi (radians).
        """
        return self.orientation_period.get(class_name, 2 * math.pi)

    # -- serialisation ------------------------------------------------------------------------

    @classmethod
    def from_dict(cls, data: Any, source: str = "eval config") -> EvalConfig:
        """Validate a config document.

        Args:
            data (Any): The document (a dict as ``serialize`` returns).
            source (str): What to call it in error messages.

        Returns:
            EvalConfig: The config.

        Raises:
            ConfigError: The document is invalid; each problem is reported with its field.
        """
        try:
            return cls.model_validate(data)
        except ValidationError as exc:
            parts = [
                f"{'.'.join(str(x) for x in e['loc']) or 'config'}: {e['msg'].removeprefix('Value error, ')}"
                for e in exc.errors()
            ]
            raise ConfigError(f"{source}: " + "; ".join(parts)) from None

    def serialize(self) -> dict[str, Any]:
        """The config as a JSON-ready dict.

        Returns:
            dict[str, Any]: Every field.
        """
        return self.model_dump(mode="json")

    @classmethod
    def deserialize(cls, data: dict[str, Any]) -> EvalConfig:
        """The inverse of ``serialize``.

        Args:
            data (dict[str, Any]): A dict as ``serialize`` returns.

        Returns:
            EvalConfig: The config.

        Raises:
            ConfigError: The document is invalid.
        """
        return cls.from_dict(data)

    def to_json(self) -> str:
        """The config as an indented JSON document.

        Returns:
            str: The document ``from_json`` and ``load`` read.
        """
        return json.dumps(self.serialize(), indent=2)

    @classmethod
    def from_json(cls, text: str, source: str = "eval config") -> EvalConfig:
        """Read a config from JSON text.

        Args:
            text (str): The JSON document.
            source (str): What to call it in error messages.

        Returns:
            EvalConfig: The config.

        Raises:
            ConfigError: The text is not JSON or the document is invalid.
        """
        try:
            data = json.loads(text)
        except (ValueError, RecursionError) as exc:  # ValueError: not JSON, a number of 4300+ digits
            raise ConfigError(f"{source}: not valid JSON: {str(exc)[:200] or 'nested too deep'}") from None
        return cls.from_dict(data, source)

    @classmethod
    def load(cls, path: str | Path) -> EvalConfig:
        """Read a config file (``fisheye-infer eval --config``).

        Args:
            path (str | Path): A JSON file.

        Returns:
            EvalConfig: The config.

        Raises:
            ConfigError: The file cannot be read, is not UTF-8 JSON, or the document is invalid.
        """
        path = Path(path)
        try:
            text = path.read_text()
        except OSError as exc:
            raise ConfigError(f"eval config {path}: cannot be read ({exc.strerror})") from exc
        except UnicodeDecodeError as exc:
            raise ConfigError(f"eval config {path}: not a JSON file (not UTF-8 text: byte {exc.start})") from None
        return cls.from_json(text, source=f"eval config {path}")
