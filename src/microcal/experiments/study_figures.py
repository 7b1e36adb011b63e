"""What a study measured: each seed's figures (:class:`SeedRun`) and their distribution.

:func:`~microcal.experiments.study.run_seed` gives a :class:`SeedRun`,
:func:`~microcal.experiments.study.run_study` a :class:`Study`; ``Study.to_json()`` is
study.json without its ``format`` (keys in docs/formats.md; NaN is the writer's to turn into
null).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

from ..control.closed_loop import ClosedLoopSummary
from ..json_value import JsonValue

if TYPE_CHECKING:
    from .adaptive_run import CurvePoint

__all__ = ["AdaptiveFigures", "Coverage", "FigureSummary", "SeedRun", "Study"]


@dataclass(frozen=True)
class AdaptiveFigures:
    """An adaptive run's own figures (study.json's ``adaptive`` of a run).

    Attributes
    ----------
    until_um : float
        The tolerance it stopped on.
    predicted_um : float
        Its predicted 95 % error of the compensated tip over the workspace when it stopped.
    inflation : float
        The factor its check on new poses put on the model's predicted error.
    stop : str
        Why it stopped.
    coverage_95 : float
        Share of the test poses whose true error lies in its predicted 95 % region (as the
        stopping rule takes it: with the inflation).
    coverage_95_model : float
        The same with the model's own prediction covariance (no inflation).
    curve, random_curve : list of CurvePoint
        Its models' true errors against poses and rig time, and those of the random design
        grown on the same seed.
    random_poses_to_match : int or None
        Poses the random design needed to reach the adaptive run's true error (None: not
        within the poses it was grown to).
    """

    until_um: float
    predicted_um: float
    inflation: float
    stop: str
    coverage_95: float
    coverage_95_model: float
    curve: list[CurvePoint]
    random_curve: list[CurvePoint]
    random_poses_to_match: int | None

    def to_json(self) -> dict[str, JsonValue]:
        """``adaptive`` of a run."""
        return {
            "until_um": self.until_um,
            "predicted_um": self.predicted_um,
            "inflation": self.inflation,
            "stop": self.stop,
            "coverage_95": self.coverage_95,
            "coverage_95_model": self.coverage_95_model,
            "random_poses_to_match": self.random_poses_to_match,
            "curve": [c.to_json() for c in self.curve],
            "random_curve": [c.to_json() for c in self.random_curve],
        }


@dataclass(frozen=True)
class Coverage:
    """How often the true error of a compensated position lay in its predicted 95 % region:
    by the model's covariance alone (``truth``) and with the measurement's added
    (``vision``); ``mean_sq`` is the mean squared Mahalanobis distance (3 when it matches)."""

    truth: float
    vision: float
    mean_sq: float

    def to_json(self) -> dict[str, JsonValue]:
        """``coverage_95.MODEL`` of a run."""
        return {"truth": self.truth, "vision": self.vision, "mean_sq": self.mean_sq}


@dataclass(frozen=True)
class SeedRun:
    """One seed of a study (one entry of study.json's ``runs``).

    The figures per model or condition are dicts in the order they were made: the models
    (``quadratic``, ``smooth``, ``auto``), ``matrix``, the ``oracle`` and, with the prior,
    ``prior``; the conditions of the evaluation besides.

    Attributes
    ----------
    seed : int
    uncalibrated_ap_truth_mean_um : float
        Mean AP_P by truth without compensation, µm.
    validation_mean_um : dict of str -> float
        Mean validation error (Eq 5.1) per model and the oracle's, µm.
    ap_truth_mean_um, ap_truth_max_um, ap_vision_mean_um : dict of str -> float
        Mean and worst AP_P per condition by truth, and the mean by the probe, µm (NaN for a
        condition that failed).
    vap_truth_mean_um : dict of str -> float
        Mean vAP per condition by truth, µm.
    coverage_95 : dict of str -> Coverage
        Per model.
    family : str
        The family the ``auto`` model chose.
    closed_loop : ClosedLoopSummary or None
        The closed loop's summary, where it was evaluated and ran.
    failed : dict of str -> str
        Conditions that could not reach a pose, and why.
    n_poses : int
        Poses measured (acquired and usable).
    render : bool
        The full pipeline ran (rendered images) instead of the projected probe.
    wall_s : float
        Wall-clock time of the seed, s.
    rig_time_s : float
        Rig time of the calibration: moves, settling, frames and (adaptive) the fits in
        between, s.
    tip_error_p95_um : dict of str -> float
        Per compensating condition (models, matrix, oracle, adaptive): the 95th percentile
        of the compensated tip's true error over test poses across the workspace, µm.
    design : str
    adaptive : AdaptiveFigures or None
        The adaptive design's own figures.
    """

    seed: int
    uncalibrated_ap_truth_mean_um: float
    validation_mean_um: dict[str, float]
    ap_truth_mean_um: dict[str, float]
    ap_truth_max_um: dict[str, float]
    ap_vision_mean_um: dict[str, float]
    vap_truth_mean_um: dict[str, float]
    coverage_95: dict[str, Coverage]
    family: str
    closed_loop: ClosedLoopSummary | None
    failed: dict[str, str]
    n_poses: int
    render: bool
    wall_s: float
    rig_time_s: float = float("nan")
    tip_error_p95_um: dict[str, float] = field(default_factory=dict)
    design: str = "random"
    adaptive: AdaptiveFigures | None = None

    def to_json(self) -> dict[str, JsonValue]:
        """The run's object in study.json. A closed loop that was evaluated but failed (see
        ``failed``) has an empty ``closed_loop`` object."""
        out: dict[str, JsonValue] = {
            "seed": self.seed,
            "uncalibrated_ap_truth_mean_um": self.uncalibrated_ap_truth_mean_um,
            "validation_mean_um": self.validation_mean_um,
            "ap_truth_mean_um": self.ap_truth_mean_um,
            "ap_truth_max_um": self.ap_truth_max_um,
            "ap_vision_mean_um": self.ap_vision_mean_um,
            "vap_truth_mean_um": self.vap_truth_mean_um,
            "coverage_95": {name: c.to_json() for name, c in self.coverage_95.items()},
            "family": self.family,
        }
        if self.closed_loop is not None:
            out["closed_loop"] = self.closed_loop.to_json()
        elif "closed_loop" in self.failed:
            out["closed_loop"] = {}
        out |= {
            "failed": self.failed,
            "n_poses": self.n_poses,
            "render": self.render,
            "wall_s": self.wall_s,
            "design": self.design,
            "rig_time_s": self.rig_time_s,
            "tip_error_p95_um": self.tip_error_p95_um,
        }
        if self.adaptive is not None:
            out["adaptive"] = self.adaptive.to_json()
        return out


@dataclass(frozen=True)
class FigureSummary:
    """One figure's distribution over the seeds: median, 90th percentile, extremes (of the
    seeds where it is finite) and how many seeds have it NaN (a condition that failed)."""

    median: float
    p90: float
    min: float
    max: float
    failed: int

    def to_json(self) -> dict[str, JsonValue]:
        """One entry of study.json's ``summary``."""
        return {
            "median": self.median,
            "p90": self.p90,
            "min": self.min,
            "max": self.max,
            "failed": self.failed,
        }


@dataclass(frozen=True)
class Study:
    """A study: its preset, seeds, each seed's run (in seed order) and the summary by
    figure name (``ap_truth_mean_um.auto``, ``validation_over_oracle.quadratic`` ...)."""

    preset: str
    seeds: list[int]
    runs: list[SeedRun]
    summary: dict[str, FigureSummary] = field(default_factory=dict)

    def to_json(self) -> dict[str, JsonValue]:
        """study.json's content without ``format``."""
        return {
            "preset": self.preset,
            "seeds": self.seeds,
            "runs": [r.to_json() for r in self.runs],
            "summary": {name: s.to_json() for name, s in self.summary.items()},
        }
