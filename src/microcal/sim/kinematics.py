"""The true kinematics of the simulated Cartesian stick-slip micromanipulator.

The end-effector's true position in {G} differs from the joint commands by the error
sources the thesis names (thesis 2.2):

- a smooth static part: axis misalignment and scale (linear), curvature and coupling
  (quadratic and cross terms), held as a polynomial :class:`KinematicModel` with known
  coefficients;
- hysteresis: an offset along each axis whose sign is the direction from which that axis
  last approached its position;
- thermal drift: a shift proportional to the temperature's departure from the reference;
- creep: after a move the end-effector keeps going, the remaining error decaying
  exponentially, ``-creep_fraction * step * exp(-t / creep_tau_s)``.

Ground truth for tests and benchmarks; the calibration itself never sees it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, as_rows
from ..kinematics.models import KinematicModel

__all__ = ["TrueKinematics", "approach_signs"]


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
    """

    static: KinematicModel
    hysteresis_um: FloatArray = field(default_factory=lambda: np.zeros(3))
    thermal_um_per_c: FloatArray = field(default_factory=lambda: np.zeros(3))
    reference_temperature_c: float = 22.0
    creep_fraction: float = 0.0
    creep_tau_s: float = 1.0

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
            +1 / -1: the direction each joint last moved in; 0 (no hysteresis) by default.
        temperature_c : float or (N,) float, optional
            Ambient temperature; the reference by default.

        Returns
        -------
        p_um : (N, 3) float
            In {G}.
        """
        d = as_rows(d_um, "d_um", 3)
        p = self.static.predict_um(d)
        if signs is not None:
            s = as_array(signs, "signs", d.shape)
            p = p + s * self.hysteresis_um
        if temperature_c is not None:
            dt = np.broadcast_to(np.asarray(temperature_c, float), (d.shape[0],))
            p = p + (dt - self.reference_temperature_c)[:, None] * self.thermal_um_per_c
        return p

    def creep_um(self, step_um: ArrayLike, elapsed_s: ArrayLike | float) -> FloatArray:
        """Remaining creep error of a move ``step_um`` (N, 3) after ``elapsed_s`` seconds."""
        step = as_rows(step_um, "step_um", 3)
        t = np.maximum(np.asarray(elapsed_s, float), 0.0)
        out: FloatArray = -self.creep_fraction * step * np.exp(-t / self.creep_tau_s)[..., None]
        return out


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
