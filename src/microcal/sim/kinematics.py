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
from ..kinematics.terms import JOINTS, polynomial_terms

__all__ = ["TrueKinematics", "approach_signs", "thesis_kinematics"]


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


def thesis_kinematics() -> TrueKinematics:
    """The `thesis` preset: errors sized after the thesis's uncalibrated figures.

    Linear couplings follow the decoupling test (Table 5-5, relative to each segment's
    start): y moves -25 µm during the 4800 µm z move (-0.00524), +3.2 µm during the 8000 µm
    x move; z moves -4.7 µm during x and +10.5 µm during y; x moves -6.1 µm during y. The
    z axis bends (-1.5e-6 µm⁻¹ dz², which with the couplings gives the large pose errors of
    Table 5-2 rows 5 and 6); y has a dx·dy coupling and x a dy² curvature of the size the
    thesis identified (section 5.2.1). Hysteresis of 0.4-0.6 µm, creep of 0.1 % of a step
    with a 0.6 s time constant, thermal drift of about 1 µm/°C.
    """
    terms = polynomial_terms(JOINTS, 2)
    names = [t.name for t in terms]
    coef = np.zeros((3, len(terms)))
    linear = np.array(
        [
            [1.000175, -0.00077, -0.00010],
            [0.00040, 1.00056, -0.00524],
            [-0.000585, 0.00132, 1.00050],
        ]
    )
    for j, joint in enumerate(JOINTS):
        coef[:, names.index(joint)] = linear[:, j]
    coef[0, names.index("dy^2")] = -4.7e-8
    coef[1, names.index("dx*dy")] = 1.5e-7
    coef[2, names.index("dz^2")] = -1.5e-6
    coef[:, names.index("1")] = [1000.0, 800.0, 300.0]  # P_B in {G}, µm
    selected = coef != 0
    static = KinematicModel(
        kind="polynomial",
        inputs=JOINTS,
        joints=JOINTS,
        terms=terms,
        coefficients=coef,
        selected=selected,
        covariance=np.zeros((3, len(terms), len(terms))),
        selection={"method": "truth"},
    )
    return TrueKinematics(
        static=static,
        hysteresis_um=np.array([0.5, 0.4, 0.6]),
        thermal_um_per_c=np.array([0.8, -0.5, 1.2]),
        reference_temperature_c=22.0,
        creep_fraction=1e-3,
        creep_tau_s=0.6,
    )
