"""Position-based visual servoing in {G} (thesis 2.3, Fig 2.6): measure, correct, repeat.

The open loop (:class:`~microcal.control.feedforward.FeedForward`) commands the joints the
identified model gives for a target and trusts them. The closed loop then measures where
the end-effector arrived, in 3D with its covariance, and corrects the joints through the
model's Jacobian, ``d <- d + J(d)^-1 (target - measured)``, until one of:

- **tolerance**: the remaining true error is within ``tolerance_um`` with probability
  ``confidence`` or more, given the measurement and its covariance (the true position is
  taken as normal about the measured one; the probability of the ball of radius
  ``tolerance_um`` about the target is computed from a fixed set of normal draws, so the
  same measurement always gives the same verdict);
- **resolution**: the correction is smaller than the positioner's resolution
  (``resolution_um``, per joint): the loop cannot do better by moving;
- **iterations**: ``max_iterations`` corrections were made.

A loop is only as good as its measurement: each iteration averages more frames as the error
shrinks (enough for the measurement's standard deviation to be about a third of the last
error, within ``frames_min``..``frames_max``). Every correction approaches its joints from
below (``approach_um`` under the command, then up), as the feed-forward does, so that the
joints' reversal error stays the same from one iteration to the next. A correction that
would leave the soft limits raises :class:`LimitError` before anything moves; an error of
the device or the cameras propagates with the tip where the last move left it. Every
iteration is passed to ``journal``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from .._validation import FloatArray, check_limits, check_number
from ..errors import DetectionError, InputError

__all__ = [
    "ServoConfig",
    "ServoResult",
    "ServoStep",
    "joint_step",
    "probability_within",
    "reachable_error",
    "servo",
    "smallest_confirmable_um",
]

#: Normal draws (fixed) for the probability of the tolerance ball.
_DRAWS = np.random.default_rng(20260).standard_normal((4000, 3))

Measure = Callable[[int], tuple[FloatArray, FloatArray]]  # frames -> (p (3,), cov (3, 3))


@dataclass(frozen=True)
class ServoConfig:
    """Settings of the closed loop (see the module docstring)."""

    tolerance_um: float = 0.5
    confidence: float = 0.9
    max_iterations: int = 6
    frames_min: int = 5
    frames_max: int = 80
    resolution_um: float = 0.005
    approach_um: float = 20.0

    def __post_init__(self) -> None:
        check_number("tolerance_um", self.tolerance_um, above=0)
        check_number("confidence", self.confidence, above=0, high=1)
        check_number("resolution_um", self.resolution_um, low=0)
        check_number("approach_um", self.approach_um, low=0)
        if not 0 <= self.max_iterations <= 100 or not 1 <= self.frames_min <= self.frames_max:
            raise InputError(
                "max_iterations: expected 0..100, frames_min..frames_max: expected 1 <= min <= max"
            )


@dataclass(frozen=True)
class ServoStep:
    """One measurement of the loop and the correction it led to (zero for the last)."""

    iteration: int
    frames: int
    d_um: FloatArray  # (3,) joints when measured
    measured_um: FloatArray  # (3,)
    cov_um2: FloatArray  # (3, 3)
    error_um: FloatArray  # (3,) target - measured
    p_within: float  # probability that the true error is within the tolerance
    correction_um: FloatArray = field(default_factory=lambda: np.zeros(3))

    def as_dict(self) -> dict[str, object]:
        """A journal line."""
        return {"iteration": self.iteration, "frames": self.frames, "d_um": self.d_um.tolist(),
                "measured_um": self.measured_um.tolist(), "cov_um2": self.cov_um2.tolist(),
                "error_um": self.error_um.tolist(), "p_within": self.p_within,
                "correction_um": self.correction_um.tolist()}  # fmt: skip


@dataclass(frozen=True)
class ServoResult:
    """Where the loop left the tip and why it stopped."""

    target_um: FloatArray
    d_um: FloatArray
    measured_um: FloatArray
    cov_um2: FloatArray
    status: Literal["tolerance", "resolution", "iterations"]
    steps: tuple[ServoStep, ...]

    @property
    def frames(self) -> int:
        """Frames grabbed in all, per camera."""
        return sum(s.frames for s in self.steps)

    @property
    def iterations(self) -> int:
        """Corrections made."""
        return len(self.steps) - 1


def _draws_of(cov_um2: FloatArray) -> FloatArray:
    """The module's fixed normal draws as N(0, cov) (4000, 3) µm (a covariance that is not
    positive definite by its diagonal alone)."""
    try:
        L = np.linalg.cholesky(cov_um2)
    except np.linalg.LinAlgError:
        L = np.diag(np.sqrt(np.maximum(np.diagonal(cov_um2), 0.0)))
    out: FloatArray = _DRAWS @ L.T
    return out


def probability_within(error_um: FloatArray, cov_um2: FloatArray, radius_um: float) -> float:
    """P(|x| <= radius) for x ~ N(error, cov), from the module's fixed normal draws."""
    x = error_um + _draws_of(cov_um2)
    return float(np.mean(np.sum(x * x, axis=1) <= radius_um**2))


def smallest_confirmable_um(cov_um2: FloatArray, confidence: float) -> float:
    """The smallest tolerance a measurement of covariance ``cov_um2`` (3, 3) µm² can confirm
    at ``confidence``: the radius holding that share of N(0, cov) (the module's draws), µm.

    Even a tip exactly on its target is confirmed within a smaller tolerance with a lower
    probability only; a loop asked for less ends on its iteration cap.
    """
    radii = np.linalg.norm(_draws_of(cov_um2), axis=1)
    return float(np.quantile(radii, confidence))


def _frames_for(last_error_um: float, last_cov: FloatArray, last_frames: int,
                config: ServoConfig) -> int:  # fmt: skip
    """Frames whose average has a standard deviation about a third of the last error."""
    sigma = float(np.sqrt(np.max(np.diagonal(last_cov))))
    want = max(last_error_um, config.tolerance_um) / 3.0
    n = int(np.ceil(last_frames * (sigma / want) ** 2)) if want > 0 else config.frames_max
    return int(np.clip(n, config.frames_min, config.frames_max))


def joint_step(J: FloatArray, e_um: FloatArray) -> FloatArray:
    """The joint step that moves the tip by ``e_um`` through the Jacobian J (3, 3), (3,) µm:
    solved exactly, or over the joints that move (non-zero columns) by least squares."""
    moving = np.any(J != 0.0, axis=0)
    if moving.all():
        return np.asarray(np.linalg.solve(J, e_um), dtype=np.float64)
    out = np.zeros(3)
    out[moving] = np.linalg.lstsq(J[:, moving], e_um, rcond=None)[0]
    return out


def reachable_error(J: FloatArray, e_um: FloatArray) -> FloatArray:
    """The part of an error (3,) µm the joints can remove: all of it when every joint moves,
    else its projection on the plane the moving joints span (held joints: zero columns)."""
    moving = np.any(J != 0.0, axis=0)
    if moving.all():
        return e_um
    out: FloatArray = J @ joint_step(J, e_um)
    return out


def servo(
    target_um: FloatArray,
    d0_um: FloatArray,
    move: Callable[[FloatArray], None],
    measure: Measure,
    jacobian: Callable[[FloatArray], FloatArray],
    limits_um: FloatArray,
    config: ServoConfig | None = None,
    journal: Callable[[ServoStep], None] | None = None,
) -> ServoResult:
    """Close the loop on a target from the joints ``d0_um`` the tip is at now.

    Parameters
    ----------
    target_um : (3,) float
        In {G}.
    d0_um : (3,) float
        The joints already commanded (the open loop's).
    move : callable ((3,) joints) -> None
        Commands the joints and returns when the tip has settled (with the approach from
        below of :attr:`ServoConfig.approach_um`).
    measure : callable (frames) -> ((3,) position, (3, 3) covariance)
        The end-effector in {G} from that many frames per camera; raises
        :class:`DetectionError` when it cannot.
    jacobian : callable ((3,) joints) -> (3, 3)
        ``d position / d joints`` of the identified model. A held joint (a two-axis
        positioner's z) has a zero column: the device reaches only a surface, so the error
        the loop removes, and judges against the tolerance, is its part along that surface.
    limits_um : (3, 2) float
        Soft limits; a correction outside raises LimitError and nothing moves.

    Raises
    ------
    LimitError
        A correction would leave the soft limits (the tip stays where it is).
    DetectionError
        A measurement failed (the tip stays where it is).
    """
    config = config or ServoConfig()
    target = np.asarray(target_um, dtype=np.float64)
    d = np.asarray(d0_um, dtype=np.float64).copy()
    steps: list[ServoStep] = []
    frames = config.frames_min
    status: Literal["tolerance", "resolution", "iterations"] = "iterations"
    for k in range(config.max_iterations + 1):
        p, cov = measure(frames)
        if not np.all(np.isfinite(p)):
            raise DetectionError(f"closed loop: iteration {k}: the end-effector was not found")
        J = jacobian(d)
        e = reachable_error(J, target - p)
        within = probability_within(e, cov, config.tolerance_um)
        step = ServoStep(k, frames, d.copy(), p, cov, e, within)
        if within >= config.confidence:
            status = "tolerance"
        elif k == config.max_iterations:
            status = "iterations"
        else:
            delta = joint_step(J, e)
            if np.all(np.abs(delta) < config.resolution_um):
                status = "resolution"
            else:
                step = ServoStep(k, frames, d.copy(), p, cov, e, within, delta)
                steps.append(step)
                if journal:
                    journal(step)
                new = d + delta
                check_limits(new[None, :], limits_um, row="correction", targets_um=target[None, :])
                move(new)
                d = new
                frames = _frames_for(float(np.linalg.norm(e)), cov, frames, config)
                continue
        steps.append(step)
        if journal:
            journal(step)
        return ServoResult(target, d, p, cov, status, tuple(steps))
    raise AssertionError("unreachable")  # the last iteration always returns
