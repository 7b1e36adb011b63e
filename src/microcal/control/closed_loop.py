"""The closed-loop condition: the feed-forward's move, then visual servoing to the target.

:class:`ClosedLoop` drives a manipulator in {G} like :class:`FeedForward` (the evaluation
runs it as one of its conditions, ``closed_loop``): the identified model's joints first,
approached from below, then the corrections of :func:`~microcal.control.visual_servo.servo`
measured by the cameras. Each target's :class:`~microcal.control.visual_servo.ServoResult`
is kept in :attr:`ClosedLoop.results`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, check_limits
from ..devices.base import Clock, Manipulator
from ..errors import DetectionError
from ..json_value import JsonValue
from ..kinematics.models import KinematicModel
from .feedforward import FeedForward
from .visual_servo import ServoConfig, ServoResult, ServoStep, reachable_error, servo

__all__ = ["CHI2_3_95", "STATUSES", "ClosedLoop", "ClosedLoopSummary"]

#: The 95 % quantile of the chi-square distribution with 3 degrees of freedom.
CHI2_3_95 = 7.814727903251178

#: measure(joints, frames) -> (position (3,), covariance (3, 3)); NaN when not found.
Measure = Callable[[FloatArray, int], tuple[FloatArray, FloatArray]]


#: How a closed loop can end (:class:`~microcal.control.visual_servo.ServoResult`'s ``status``).
STATUSES = ("tolerance", "resolution", "iterations")


@dataclass(frozen=True)
class ClosedLoopSummary:
    """How the closed loop went over the targets it was sent to (results.json's
    ``closed_loop``).

    Attributes
    ----------
    tolerance_um, confidence : float
        What the loop aimed at (:class:`~microcal.control.visual_servo.ServoConfig`).
    targets : int
    iterations_mean, frames_mean : float
        Corrections and frames per camera per target, on average.
    iterations_max, frames_max : int
    status : dict of str -> int
        Targets per way the loop ended (:data:`STATUSES`).
    truth_within_tolerance, truth_in_measured_95 : float or None
        On the simulator: the share of targets whose true error is within the tolerance, and
        inside the last measurement's 95 % region; None without ground truth.
    """

    tolerance_um: float
    confidence: float
    targets: int
    iterations_mean: float
    iterations_max: int
    frames_mean: float
    frames_max: int
    status: dict[str, int]
    truth_within_tolerance: float | None = None
    truth_in_measured_95: float | None = None

    def to_json(self) -> dict[str, JsonValue]:
        """The ``closed_loop`` object (the ground truth's shares only where known)."""
        out: dict[str, JsonValue] = {
            "tolerance_um": self.tolerance_um,
            "confidence": self.confidence,
            "targets": self.targets,
            "iterations_mean": self.iterations_mean,
            "iterations_max": self.iterations_max,
            "frames_mean": self.frames_mean,
            "frames_max": self.frames_max,
            "status": self.status,
        }
        if self.truth_within_tolerance is not None:
            out["truth_within_tolerance"] = self.truth_within_tolerance
        if self.truth_in_measured_95 is not None:
            out["truth_in_measured_95"] = self.truth_in_measured_95
        return out


class ClosedLoop(FeedForward):
    """A manipulator driven to positions in {G} with vision in the loop.

    Parameters
    ----------
    manipulator : Manipulator
    model : KinematicModel
    measure : callable (joints, frames) -> (position, covariance)
        E.g. ``VisionProbe.measure_with_covariance``.
    clock : Clock
    extra : callable () -> extra inputs, optional
        As for :class:`FeedForward`.
    config : ServoConfig, optional
    settle_s : float
        Wait after each move before measuring.
    journal : callable (ServoStep) -> None, optional
        Receives every iteration.
    truth : callable () -> (3,) float, optional
        The simulator's true position, recorded after each target (:attr:`truth_um`) for
        figures of how well the loop knows where it is; never used by the loop.
    """

    def __init__(
        self,
        manipulator: Manipulator,
        model: KinematicModel,
        measure: Measure,
        clock: Clock,
        extra: Callable[[], ArrayLike] | None = None,
        config: ServoConfig | None = None,
        settle_s: float = 1.0,
        journal: Callable[[ServoStep], None] | None = None,
        truth: Callable[[], FloatArray] | None = None,
    ) -> None:
        super().__init__(manipulator, model, "optimal", extra, clock)
        self.config = config or ServoConfig()
        self.approach_um = self.config.approach_um  # every move arrives from below
        self.measure = measure
        self.settle_s = float(settle_s)
        self.journal = journal
        self.results: list[ServoResult] = []
        self.truth = truth
        self.truth_um: list[FloatArray] = []
        self._last_d = np.zeros(len(model.joints))

    def _move_joints(self, d_um: FloatArray) -> None:
        start = self.manipulator.below_um(d_um, self.approach_um)
        check_limits(np.vstack([start, d_um]), self.manipulator.limits_um, row="correction",
                     owner=self.manipulator.name)  # fmt: skip
        assert self.clock is not None
        self.manipulator.move_to_um(start)
        self.manipulator.wait_until_stopped(self.clock)
        self.manipulator.move_to_um(d_um)
        self.manipulator.wait_until_stopped(self.clock)
        self.clock.sleep(self.settle_s)

    def _jacobian(self, d_um: FloatArray) -> FloatArray:
        extra = None if self.extra is None else np.asarray(self.extra(), dtype=np.float64)
        u = d_um if extra is None else np.concatenate([d_um, extra])
        out: FloatArray = self.model.jacobian(u)[0]
        return out

    def move_to_position_um(self, p_um: ArrayLike) -> FloatArray:
        """Open loop to ``p_um``, then corrections until the loop stops; returns the joints.

        Raises
        ------
        LimitError
            The open-loop joints or a correction leave the soft limits (nothing more moves).
        DetectionError
            The cameras lost the end-effector (the tip stays where the last move left it).
        """
        target = np.asarray(p_um, dtype=np.float64)
        d0 = super().move_to_position_um(target)
        assert self.clock is not None
        self.manipulator.wait_until_stopped(self.clock)
        self.clock.sleep(self.settle_s)

        def measure(frames: int) -> tuple[FloatArray, FloatArray]:
            p, cov = self.measure(self._last_d, frames)
            if not np.all(np.isfinite(p)):
                raise DetectionError(
                    f"{self.manipulator.name}: closed loop: the cameras lost the end-effector "
                    f"near {np.round(target, 3).tolist()} µm; the tip was left where it is"
                )
            return p, cov

        self._last_d = d0

        def move(d: FloatArray) -> None:
            self._move_joints(d)
            self._last_d = d

        result = servo(target, d0, move, measure, self._jacobian, self.manipulator.limits_um,
                       self.config, self.journal)  # fmt: skip
        self.results.append(result)
        if self.truth is not None:
            self.truth_um.append(np.asarray(self.truth(), dtype=np.float64))
        return result.d_um

    def summary(self) -> ClosedLoopSummary:
        """The ``closed_loop`` object of results.json: iterations, frames and how the loops
        ended, and on the simulator how often the true error was within the tolerance and
        within the last measurement's 95 % region."""
        r = self.results
        within = in_95 = None
        if self.truth_um and len(self.truth_um) == len(r):
            e = np.array([t - x.target_um for t, x in zip(self.truth_um, r, strict=True)])
            m2 = [float(v @ np.linalg.solve(x.cov_um2, v))
                  for v, x in zip(e - np.array([x.measured_um - x.target_um for x in r]), r,
                                  strict=True)]  # fmt: skip
            if self.model.held_um:  # a surface: the error along it is what the loop removes
                e = np.array([reachable_error(self._jacobian(x.d_um), v)
                              for v, x in zip(e, r, strict=True)])  # fmt: skip
            within = float(np.mean(np.linalg.norm(e, axis=1) <= self.config.tolerance_um))
            in_95 = float(np.mean(np.array(m2) <= CHI2_3_95))
        return ClosedLoopSummary(
            tolerance_um=self.config.tolerance_um,
            confidence=self.config.confidence,
            targets=len(r),
            iterations_mean=float(np.mean([x.iterations for x in r])) if r else 0.0,
            iterations_max=max((x.iterations for x in r), default=0),
            frames_mean=float(np.mean([x.frames for x in r])) if r else 0.0,
            frames_max=max((x.frames for x in r), default=0),
            status={s: sum(x.status == s for x in r) for s in STATUSES},
            truth_within_tolerance=within,
            truth_in_measured_95=in_95,
        )
