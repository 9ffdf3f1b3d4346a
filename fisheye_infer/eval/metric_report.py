"""What the FDS/mAP metric produces: the curves (``MetricData``), the per-class and summary numbers, the report.

``MetricData`` holds one class's precision, confidence and TP-error curves at one threshold;
``ClassMetrics`` and ``Summary`` the numbers drawn from them; ``MetricsReport`` everything one
evaluation produced (JSON and Markdown). The settings they were computed with are
[`EvalConfig`][fisheye_infer.eval.metric_config.EvalConfig].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, computed_field

from fisheye_infer.eval.metric_config import EvalConfig

__all__ = ["MetricData", "ClassMetrics", "Summary", "MetricsReport", "TP_METRICS"]

#: The TP error curves the Fisheye3DOD metric keeps (velocity and attribute errors are dropped).
TP_METRICS = ("trans_err", "scale_err", "orient_err")


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
