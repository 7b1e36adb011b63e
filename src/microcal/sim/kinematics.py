"""The true kinematics of the simulated Cartesian stick-slip micromanipulator.

The end-effector's true position in {G} differs from the joint commands by the error
sources the thesis names (thesis 2.2):

- a smooth static part: axis misalignment and scale (linear), curvature and coupling
  (quadratic and cross terms), held as a polynomial :class:`KinematicModel` with known
  coefficients;
- optionally, errors outside any polynomial (:class:`JointErrors`, the ``population``
  preset): smooth guideway straightness and angular errors of each joint, the angles seen
  at the tool through its offset from the guideways (Abbe error), and a periodic error of
  each joint's position sensor;
- hysteresis: an offset along each axis whose sign is the direction from which that axis
  last approached its position, its size changing linearly along the travel if
  ``hysteresis_slope`` is set; with ``play`` (:mod:`~microcal.sim.motion`), the direction
  is a play-operator sum in [-1, 1] that remembers how far the joint travelled since it
  last turned (the manipulator keeps that memory and passes it as ``signs``);
- thermal drift: a shift proportional to the temperature's departure from the reference;
- creep: after a move the end-effector keeps going, the remaining error decaying
  exponentially, ``-creep_fraction * step * exp(-t / creep_tau_s)``, or logarithmically
  (``creep_law="log"``): ``-creep_fraction * step * (1 - ln(1 + t/tau) / ln(1 + T/tau))``
  until ``T = creep_end_s``, as piezo creep does over decades of time.

Ground truth for tests and benchmarks; the calibration itself never sees it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike
from scipy.interpolate import CubicSpline

from .._validation import FloatArray, as_array, as_rows
from ..errors import DegenerateDataError
from ..kinematics.models import KinematicModel
from .motion import PlayHysteresis

__all__ = ["JointErrors", "TrueKinematics", "approach_signs", "invert_map"]


def invert_map(
    fn: Callable[[FloatArray], FloatArray],
    p_um: FloatArray,
    d0_um: FloatArray,
    iterations: int = 20,
    tol_um: float = 1e-9,
    step_um: float = 1e-2,
) -> FloatArray:
    """Joints ``d`` with ``fn(d) = p_um``: chord iterations (Newton with the central-difference
    Jacobian of the start, taken again only when an iteration fails to halve the residual).

    Parameters
    ----------
    fn : callable (N, 3) -> (N, 3)
        Joints to positions, µm.
    p_um : (N, 3) float
    d0_um : (N, 3) float
        Where to start.

    Raises
    ------
    DegenerateDataError
        No convergence to 1e-6 µm (a target the map cannot reach).
    """
    d = np.array(d0_um, dtype=np.float64)
    J: FloatArray | None = None
    previous = np.inf
    for _ in range(iterations):
        r = fn(d) - p_um
        size = float(np.max(np.abs(r)))
        if size < tol_um:
            return d
        if J is None or size > 0.5 * previous:
            J = np.empty((p_um.shape[0], 3, 3))
            for b in range(3):
                e = np.zeros(3)
                e[b] = step_um
                J[:, :, b] = (fn(d + e) - fn(d - e)) / (2 * step_um)
        previous = size
        d = d - np.linalg.solve(J, r[:, :, None])[:, :, 0]
    r = fn(d) - p_um
    if np.max(np.abs(r)) >= 1e-6:
        raise DegenerateDataError(
            f"the map cannot reach the target (residual {np.abs(r).max():.3g} µm)"
        )
    return d


@dataclass(frozen=True, eq=False)
class JointErrors:
    """Errors of each joint that follow no polynomial: each a function of one joint's value.

    Attributes
    ----------
    knots_um : (3, K) float
        Where each joint's profiles are given (increasing), µm.
    straightness_um : (3, K, 3) float
        Joint j's guideway deviation at its knots, in {G} (x, y, z), µm; a cubic spline
        between the knots.
    angles_urad : (3, K, 3) float
        Joint j's carriage rotation (about {G}'s x, y, z) at its knots, µrad; seen at the
        tool as ``angle x tool_offset_um`` (Abbe error).
    tool_offset_um : (3,) float
        The tool point's offset from the guideways' reference point, µm.
    periodic_um, periodic_period_um, periodic_phase : (3,) float
        A sinusoidal error of each joint's position sensor, along that joint's axis:
        amplitude, period and phase.
    """

    knots_um: FloatArray
    straightness_um: FloatArray
    angles_urad: FloatArray
    tool_offset_um: FloatArray
    periodic_um: FloatArray
    periodic_period_um: FloatArray
    periodic_phase: FloatArray

    def __post_init__(self) -> None:
        profiles = self.straightness_um + 1e-6 * np.cross(self.angles_urad, self.tool_offset_um)
        splines = [CubicSpline(self.knots_um[j], profiles[j], axis=0) for j in range(3)]
        object.__setattr__(self, "_splines", splines)

    def smooth_um(self, d_um: FloatArray) -> FloatArray:
        """Straightness and Abbe errors at joints ``d_um`` (N, 3); (N, 3) µm in {G}."""
        out = np.zeros((d_um.shape[0], 3))
        for j, spline in enumerate(self._splines):  # type: ignore[attr-defined]
            out += spline(d_um[:, j])
        return out

    def periodic_err_um(self, d_um: FloatArray) -> FloatArray:
        """The sensors' periodic errors, (N, 3) µm (joint j's along axis j)."""
        phase = 2 * np.pi * d_um / self.periodic_period_um + self.periodic_phase
        out: FloatArray = self.periodic_um * np.sin(phase)
        return out

    def __call__(self, d_um: FloatArray) -> FloatArray:
        """All of them, (N, 3) µm."""
        return self.smooth_um(d_um) + self.periodic_err_um(d_um)


@dataclass(frozen=True, eq=False)
class TrueKinematics:
    """Parameters of the true kinematics (see the module docstring).

    Attributes
    ----------
    static : KinematicModel
        The smooth part, joints in µm to {G} in µm (includes the base position P_B).
    hysteresis_um : (3,) float
        Half the gap between the two approach directions, per joint, along that joint's axis.
    thermal_um_per_c : (3,) float
        Shift of the end-effector in {G} per °C away from ``reference_temperature_c``.
    reference_temperature_c : float
    creep_fraction : float
        Remaining error right after a move, as a fraction of the step (per joint).
    creep_tau_s : float
        Time constant of the creep.
    joint_errors : JointErrors, optional
        The errors outside the polynomial (none by default).
    hysteresis_slope : (3,) float
        Relative change of each joint's half gap per half travel from ``hysteresis_centre_um``
        (0: constant).
    hysteresis_centre_um, hysteresis_half_travel_um : (3,) float
    creep_law : {"exp", "log"}
    creep_end_s : float
        For the logarithmic law: when the creep has ended.
    play : PlayHysteresis, optional
        Reversal error with memory (none by default: the sign of the last move alone).
    """

    static: KinematicModel
    hysteresis_um: FloatArray = field(default_factory=lambda: np.zeros(3))
    thermal_um_per_c: FloatArray = field(default_factory=lambda: np.zeros(3))
    reference_temperature_c: float = 22.0
    creep_fraction: float = 0.0
    creep_tau_s: float = 1.0
    joint_errors: JointErrors | None = None
    hysteresis_slope: FloatArray = field(default_factory=lambda: np.zeros(3))
    hysteresis_centre_um: FloatArray = field(default_factory=lambda: np.zeros(3))
    hysteresis_half_travel_um: FloatArray = field(default_factory=lambda: np.ones(3))
    creep_law: str = "exp"
    creep_end_s: float = 60.0
    play: PlayHysteresis | None = None

    def hysteresis_at_um(self, d_um: FloatArray) -> FloatArray:
        """Each joint's half gap at joints ``d_um`` (N, 3), µm."""
        rel = (d_um - self.hysteresis_centre_um) / self.hysteresis_half_travel_um
        out: FloatArray = self.hysteresis_um * (1.0 + self.hysteresis_slope * rel)
        return out

    def position_um(
        self,
        d_um: ArrayLike,
        signs: ArrayLike | None = None,
        temperature_c: ArrayLike | float | None = None,
    ) -> FloatArray:
        """True settled position (creep finished) for joint values and approach directions.

        Parameters
        ----------
        d_um : (N, 3) or (3,) float
            Joint values, µm.
        signs : (N, 3) float, optional
            +1 / -1: the direction each joint last moved in (or, with ``play``, the
            effective direction in [-1, 1]); 0 (no hysteresis) by default.
        temperature_c : float or (N,) float, optional
            Ambient temperature; the reference by default.

        Returns
        -------
        p_um : (N, 3) float
            In {G}.
        """
        d = as_rows(d_um, "d_um", 3)
        p = self.static.predict_um(d)
        if self.joint_errors is not None:
            p = p + self.joint_errors(d)
        if signs is not None:
            s = as_array(signs, "signs", d.shape)
            p = p + s * self.hysteresis_at_um(d)
        if temperature_c is not None:
            dt = np.broadcast_to(np.asarray(temperature_c, float), (d.shape[0],))
            p = p + (dt - self.reference_temperature_c)[:, None] * self.thermal_um_per_c
        return p

    def creep_um(self, step_um: ArrayLike, elapsed_s: ArrayLike | float) -> FloatArray:
        """Remaining creep error of a move ``step_um`` (N, 3) after ``elapsed_s`` seconds."""
        step = as_rows(step_um, "step_um", 3)
        t = np.maximum(np.asarray(elapsed_s, float), 0.0)
        if self.creep_law == "log":
            tau, end = self.creep_tau_s, self.creep_end_s
            left = np.clip(1.0 - np.log1p(t / tau) / np.log1p(end / tau), 0.0, 1.0)
        else:
            left = np.exp(-t / self.creep_tau_s)
        out: FloatArray = -self.creep_fraction * step * np.asarray(left)[..., None]
        return out

    def solve_um(
        self,
        p_um: ArrayLike,
        signs: ArrayLike | None = None,
        temperature_c: ArrayLike | float | None = None,
        iterations: int = 20,
        tol_um: float = 1e-9,
    ) -> FloatArray:
        """The joints whose settled true position is ``p_um``: the truth inverted exactly.

        Newton iterations on :meth:`position_um` with a central-difference Jacobian, started
        at the static model's linear part; the oracle compensator.

        Parameters
        ----------
        p_um : (N, 3) float
        signs : (N, 3) float, optional
            Approach directions the joints will arrive with.
        temperature_c : float or (N,) float, optional

        Raises
        ------
        DegenerateDataError
            If the iteration does not converge to ``tol_um`` (a target the truth cannot reach).
        """
        p = as_rows(p_um, "p_um", 3)
        d0 = np.asarray(np.linalg.solve(self.static.R, (p - self.static.p_base_um).T).T, np.float64)
        return invert_map(lambda d: self.position_um(d, signs, temperature_c), p, d0,
                          iterations, tol_um)  # fmt: skip


def approach_signs(d_um: ArrayLike, start_um: ArrayLike | None = None) -> FloatArray:
    """Direction each joint last moved in, along a sequence of commands.

    Parameters
    ----------
    d_um : (N, 3) float
        Commands in the order they are executed.
    start_um : (3,) float, optional
        Where the joints were before the first command; zero by default.

    Returns
    -------
    signs : (N, 3) float
        +1 or -1; a joint that did not move keeps its previous sign (+1 at the start).
    """
    d = as_rows(d_um, "d_um", 3)
    prev = np.zeros(3) if start_um is None else as_array(start_um, "start_um", (3,))
    steps = np.diff(np.vstack([prev, d]), axis=0)
    signs = np.empty_like(d)
    current = np.ones(3)
    for i, step in enumerate(steps):
        current = np.where(step > 0, 1.0, np.where(step < 0, -1.0, current))
        signs[i] = current
    return signs
