"""The simulator's `thesis` preset kinematics, sized after the thesis's uncalibrated figures."""

from __future__ import annotations

import numpy as np

from ..kinematics.models import KinematicModel
from ..kinematics.terms import JOINTS, polynomial_terms
from .kinematics import TrueKinematics

__all__ = ["thesis_kinematics"]


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
