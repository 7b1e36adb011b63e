"""What the evaluation tests measured, per source and condition (results.json's sections).

Each test of :mod:`~microcal.procedures.evaluation` and :mod:`~microcal.procedures.iso_tests`
gives ``{source: {condition: figures}}`` (:data:`BySource`): the sources are ``vision`` (the
calibrated cameras) and, on the simulator, ``truth``; the conditions are the compensators
compared (``uncalibrated``, ``matrix``, ``optimal``, ``closed_loop`` ...). An
:class:`Evaluation` holds the tests that ran; its :meth:`~Evaluation.to_json` is what
results.json stores of them (NaN is the writer's to turn into null).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import TypeAlias, TypeVar

import numpy as np

from .._validation import FloatArray
from ..control.closed_loop import ClosedLoopSummary
from ..json_value import JsonValue
from ..metrics import DecouplingResult, DistanceStatistics, PoseStatistics

__all__ = [
    "BySource",
    "DecouplingFigures",
    "DirectionalPose",
    "DriftFigures",
    "Evaluation",
    "MultiDirectionalFigures",
    "PoseAccuracyFigures",
    "StabilisationFigures",
]

F = TypeVar("F")
#: Figures per source (``vision``, ``truth``) and condition.
BySource: TypeAlias = dict[str, dict[str, F]]


@dataclass(frozen=True)
class PoseAccuracyFigures:
    """ISO 9283 pose accuracy and repeatability of one condition (clauses 7.2.1, 7.2.2).

    ``vap_um`` and ``max_vap_um`` (the multi-directional variation, clause 7.3) are set where
    that test's figures join these (the demo's results.json).
    """

    mean_ap_p_um: float  # NaN when no pose was measured
    max_ap_p_um: float
    poses: list[PoseStatistics] = field(default_factory=list)
    vap_um: float | None = None
    max_vap_um: float | None = None

    def to_json(self) -> dict[str, JsonValue]:
        """``pose_accuracy.SOURCE.CONDITION`` of results.json."""
        out: dict[str, JsonValue] = {
            "mean_ap_p_um": self.mean_ap_p_um,
            "max_ap_p_um": self.max_ap_p_um,
            "poses": [s.as_dict() for s in self.poses],
        }
        if self.vap_um is not None:
            out |= {"vap_um": self.vap_um, "max_vap_um": self.max_vap_um}
        return out


@dataclass(frozen=True)
class DirectionalPose:
    """One pose of the multi-directional test: its displacement from home and its vAP, µm."""

    desired_um: FloatArray  # (3,)
    vap_um: float

    def to_json(self) -> dict[str, JsonValue]:
        """One of ``poses``."""
        return {"desired_um": self.desired_um.tolist(), "vap_um": self.vap_um}


@dataclass(frozen=True)
class MultiDirectionalFigures:
    """ISO 9283 multi-directional pose accuracy variation of one condition (clause 7.3)."""

    vap_um: float  # mean over the poses; NaN when none was measured
    max_vap_um: float
    poses: list[DirectionalPose] = field(default_factory=list)

    def to_json(self) -> dict[str, JsonValue]:
        """The figures with each pose's."""
        return {
            "vap_um": self.vap_um,
            "max_vap_um": self.max_vap_um,
            "poses": [p.to_json() for p in self.poses],
        }


@dataclass(frozen=True)
class DecouplingFigures:
    """The decoupling test of one condition (Fig 5.5): its figures and the samples.

    Attributes
    ----------
    metrics : DecouplingResult
        Undesired displacement ranges and Ω per axis.
    samples_um : (N, 3) float
        Every sample of the path as measured (NaN where it could not be).
    segment : (N,) int
        The axis moving at each sample.
    """

    metrics: DecouplingResult
    samples_um: FloatArray
    segment: np.ndarray

    def to_json(self) -> dict[str, JsonValue]:
        """``decoupling.SOURCE.CONDITION`` of results.json, with the samples."""
        return {
            **self.metrics.as_dict(),
            "samples_um": self.samples_um.tolist(),
            "segment": self.segment.tolist(),
        }


@dataclass(frozen=True)
class StabilisationFigures:
    """ISO 9283 pose stabilisation time of one condition (clause 7.5).

    ``times_s`` has one entry per cycle, None where the pose did not settle within the
    window; ``max_s`` is None unless every cycle settled.
    """

    band_um: float
    window_s: float
    times_s: list[float | None]
    mean_s: float | None
    max_s: float | None

    def to_json(self) -> dict[str, JsonValue]:
        """``stabilisation.SOURCE.CONDITION`` of results.json."""
        return {
            "band_um": self.band_um,
            "window_s": self.window_s,
            "times_s": self.times_s,
            "mean_s": self.mean_s,
            "max_s": self.max_s,
        }


@dataclass(frozen=True)
class DriftFigures:
    """ISO 9283 drift of pose accuracy of one condition (clause 7.7): AP_P at each visit."""

    t_s: list[float]  # since the first visit
    ap_p_um: list[float]
    drift_ap_um: float | None  # |AP(last) - AP(first)|; None with fewer than two visits

    def to_json(self) -> dict[str, JsonValue]:
        """``drift.SOURCE.CONDITION`` of results.json."""
        return {"t_s": self.t_s, "ap_p_um": self.ap_p_um, "drift_ap_um": self.drift_ap_um}


def _section(
    figures: Mapping[str, Mapping[str, F]], to_json: Callable[[F], JsonValue]
) -> dict[str, JsonValue]:
    return {
        source: {name: to_json(f) for name, f in per.items()} for source, per in figures.items()
    }


@dataclass
class Evaluation:
    """The evaluation tests that ran (None: not run), in results.json's order."""

    pose_accuracy: BySource[PoseAccuracyFigures] | None = None
    decoupling: BySource[DecouplingFigures] | None = None
    distance_accuracy: BySource[DistanceStatistics] | None = None
    stabilisation: BySource[StabilisationFigures] | None = None
    drift: BySource[DriftFigures] | None = None
    closed_loop: ClosedLoopSummary | None = None
    #: The measurements the cameras could not make (their poses are left out of the figures
    #: by vision): ``{"d_um": [3], "reason": str}`` each, in the order they were tried.
    unseen: list[dict[str, JsonValue]] = field(default_factory=list)

    def to_json(self) -> dict[str, JsonValue]:
        """The sections of results.json the tests give (those that ran)."""
        out: dict[str, JsonValue] = {}
        if self.pose_accuracy is not None:
            out["pose_accuracy"] = _section(self.pose_accuracy, PoseAccuracyFigures.to_json)
        if self.decoupling is not None:
            out["decoupling"] = _section(self.decoupling, DecouplingFigures.to_json)
        if self.distance_accuracy is not None:
            out["distance_accuracy"] = _section(self.distance_accuracy, DistanceStatistics.as_dict)
        if self.stabilisation is not None:
            out["stabilisation"] = _section(self.stabilisation, StabilisationFigures.to_json)
        if self.drift is not None:
            out["drift"] = _section(self.drift, DriftFigures.to_json)
        if self.closed_loop is not None:
            out["closed_loop"] = self.closed_loop.to_json()
        if self.unseen:
            out["unseen"] = list(self.unseen)
        return out
