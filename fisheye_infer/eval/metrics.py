"""What the metric is configured with and what it produces: ``EvalConfig``, ``MetricData``, ``MetricsReport``.

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
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, computed_field, model_validator

from fisheye_infer.errors import ConfigError
from fisheye_infer.runtime.records import CLASSES

__all__ = ["EvalConfig", "MetricData", "ClassMetrics", "Summary", "MetricsReport", "TP_METRICS", "REFERENCE_RANGE"]

#: The TP error curves the Fisheye3DOD metric keeps (velocity and attribute errors are dropped).
TP_METRICS = ("trans_err", "scale_err", "orient_err")
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


@dataclass(frozen=True, eq=False)
class MetricData:
    """One class at one threshold: precision, confidence and TP-error curves at 101 recall points."""

    recall: np.ndarray
    precision: np.ndarray
    confidence: np.ndarray
    trans_err: np.ndarray
    scale_err: np.ndarray
    orient_err: np.ndarray

    nelem: ClassVar[int] = 101

    def __post_init__(self) -> None:
        for name in ("recall", "precision", "confidence", *TP_METRICS):
            if np.shape(getattr(self, name)) != (self.nelem,):
                raise ValueError(
                    f"{name}: expected {self.nelem} recall points, got shape {np.shape(getattr(self, name))}"
                )

    @classmethod
    def no_predictions(cls) -> MetricData:
        """No ground truth or no match: precision and confidence 0, every TP error 1."""
        ones = np.ones(cls.nelem)
        return cls(
            np.linspace(0, 1, cls.nelem), np.zeros(cls.nelem), np.zeros(cls.nelem), ones, ones.copy(), ones.copy()
        )

    @property
    def max_recall_ind(self) -> int:
        """Index of the last recall point with a non-zero confidence (0 if none)."""
        nonzero = np.nonzero(self.confidence)[0]
        return int(nonzero[-1]) if len(nonzero) else 0

    def serialize(self) -> dict[str, list[float]]:
        return {name: getattr(self, name).tolist() for name in ("recall", "precision", "confidence", *TP_METRICS)}

    @classmethod
    def deserialize(cls, data: dict[str, list[float]]) -> MetricData:
        return cls(
            **{name: np.asarray(data[name], np.float64) for name in ("recall", "precision", "confidence", *TP_METRICS)}
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, MetricData):
            return NotImplemented
        return all(
            np.array_equal(getattr(self, n), getattr(other, n))
            for n in ("recall", "precision", "confidence", *TP_METRICS)
        )


class ClassMetrics(BaseModel):
    """One class: AP per threshold and its mean, and the TP errors at ``dist_th_tp``."""

    model_config = ConfigDict(frozen=True)

    ap: float
    ap_by_threshold: dict[str, float] = Field(description="threshold (m, as text) -> AP")
    trans_err: float = Field(description="ATE, metres")
    scale_err: float = Field(description="ASE, 1 - IoU")
    orient_err: float = Field(description="AOE, radians")


class Summary(BaseModel):
    """The headline numbers and per-class results for one set of class ranges."""

    model_config = ConfigDict(frozen=True)

    ref_range: float | None = Field(description="reference range the class ranges were scaled to (None: as configured)")
    FDS: float
    mAP: float
    mATE: float
    mASE: float
    mAOE: float
    classes: dict[str, ClassMetrics]
    num_gt: int = Field(description="ground-truth boxes inside the class ranges")
    num_pred: int = Field(description="predictions inside the class ranges")


class MetricsReport(BaseModel):
    """Everything one evaluation produced: the main summary, the distance breakdown, the config.

    ``FDS``, ``mAP``, ``mATE``, ``mASE`` and ``mAOE`` repeat the main summary's (also at the top of the JSON
    document). FDS and mAP are shares in [0, 1]; mATE in metres, mASE as 1 - IoU, mAOE in radians.

    Attributes:
        main (Summary): The headline numbers and per-class results (``main.classes[name].ap``, ``.trans_err``,
            ...) at the configured class ranges.
        distance (dict[str, Summary]): ``"0-30 m"``, ``"0-48 m"``, ...: the same metric with the class ranges
            scaled to r / 48.
        num_samples (int): Samples scored.
        config (EvalConfig): The settings used.
        eval_seconds (float): Time the evaluation took, seconds.
    """

    model_config = ConfigDict(frozen=True)

    main: Summary
    distance: dict[str, Summary] = Field(
        description="'0-30 m', '0-48 m', ...: the same metric with class ranges scaled to r / 48"
    )
    num_samples: int
    config: EvalConfig
    eval_seconds: float = 0.0

    # The headline figures at the top of the JSON document too, where a script looks first.
    @computed_field  # type: ignore[prop-decorator]
    @property
    def FDS(self) -> float:
        """The main summary's FDS (Fisheye Detection Score), in [0, 1]."""
        return self.main.FDS

    @computed_field  # type: ignore[prop-decorator]
    @property
    def mAP(self) -> float:
        """The main summary's mean AP over classes and thresholds, in [0, 1]."""
        return self.main.mAP

    @computed_field  # type: ignore[prop-decorator]
    @property
    def mATE(self) -> float:
        """The main summary's mean translation error, metres."""
        return self.main.mATE

    @computed_field  # type: ignore[prop-decorator]
    @property
    def mASE(self) -> float:
        """The main summary's mean scale error, 1 - IoU."""
        return self.main.mASE

    @computed_field  # type: ignore[prop-decorator]
    @property
    def mAOE(self) -> float:
        """The main summary's mean orientation error, radians."""
        return self.main.mAOE

    def details(self) -> dict[str, float]:
        """The official evaluator's flat keys, for side-by-side checks.

        Returns:
            dict[str, float]: ``mAP``, ``mATE``, ``mASE``, ``mAOE``, ``NDS`` (the FDS), and per class
                ``Car_AP``, ``Car_ATE``, ..., ``Car_AP@0.5``, ...
        """
        m = self.main
        out = {"mAP": m.mAP, "mATE": m.mATE, "mASE": m.mASE, "mAOE": m.mAOE, "NDS": m.FDS}
        for name, c in m.classes.items():
            out.update(
                {
                    f"{name}_AP": c.ap,
                    f"{name}_ATE": c.trans_err,
                    f"{name}_ASE": c.scale_err,
                    f"{name}_AOE": c.orient_err,
                }
            )
            out.update({f"{name}_AP@{t}": v for t, v in c.ap_by_threshold.items()})
        return out

    def to_json(self, indent: int | None = 2) -> str:
        """The report as a JSON document.

        Args:
            indent (int | None): Indentation (None: one line).

        Returns:
            str: The document ``from_json`` reads.
        """
        return self.model_dump_json(indent=indent)

    @classmethod
    def from_json(cls, text: str) -> MetricsReport:
        """Read back what ``to_json`` wrote.

        Args:
            text (str): The JSON document.

        Returns:
            MetricsReport: The report.

        Raises:
            pydantic.ValidationError: The text is not a report.
        """
        return cls.model_validate_json(text)

    def to_markdown(self) -> str:
        """Paper-style Markdown tables: the headline, per class, and the distance breakdown.

        Returns:
            str: The tables; FDS and AP in percent, ATE in metres, ASE as 1 - IoU, AOE in radians.
        """
        m = self.main
        ths = list(next(iter(m.classes.values())).ap_by_threshold) if m.classes else []
        lines = [
            "# Fisheye3DOD evaluation",
            "",
            f"{self.num_samples} samples, {m.num_gt} ground-truth boxes and {m.num_pred} predictions "
            "within the class ranges.",
            "FDS, mAP and AP in %; mATE in m, mASE as 1 - IoU, mAOE in rad.",
            "",
            "| FDS | mAP | mATE | mASE | mAOE |",
            "|---:|---:|---:|---:|---:|",
            f"| {100 * m.FDS:.1f} | {100 * m.mAP:.1f} | {m.mATE:.3f} | {m.mASE:.3f} | {m.mAOE:.3f} |",
            "",
            "## Per class",
            "",
            "| class | AP | " + " | ".join(f"AP@{t}" for t in ths) + " | ATE | ASE | AOE |",
            "|---|---:|" + "---:|" * len(ths) + "---:|---:|---:|",
        ]
        for name, c in m.classes.items():
            aps = " | ".join(f"{100 * v:.1f}" for v in c.ap_by_threshold.values())
            lines.append(
                f"| {name} | {100 * c.ap:.1f} | {aps} | {c.trans_err:.3f} | {c.scale_err:.3f} | {c.orient_err:.3f} |"
            )
        if self.distance:
            names = list(m.classes)
            lines += [
                "",
                "## Distance",
                "",
                "Class ranges scaled to r / 48 of 48/48/48/48/36/42 m, for ground truth and predictions alike.",
                "",
                "| range | FDS | mAP | mATE | mASE | mAOE | " + " | ".join(names) + " |",
                "|---|---:|---:|---:|---:|---:|" + "---:|" * len(names),
            ]
            for label, s in self.distance.items():
                aps = " | ".join(f"{100 * s.classes[n].ap:.1f}" for n in names)
                lines.append(
                    f"| {label} | {100 * s.FDS:.1f} | {100 * s.mAP:.1f} | "
                    f"{s.mATE:.3f} | {s.mASE:.3f} | {s.mAOE:.3f} | {aps} |"
                )
        return "\n".join(lines) + "\n"
