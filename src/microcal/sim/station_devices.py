"""The further devices of the ``thesis-platform`` preset: a second manipulator and a positioner.

The thesis's platform (section 2.4) carries two micromanipulators and an X-Y positioner
under one vision system; the preset gives the simulator the same: manipulator ``m1`` (the
``thesis`` preset's, unchanged), manipulator ``m2`` and positioner ``p1``, each with a board
(its end-effector's target) and its own true kinematics in the one frame {G}:

- ``m2``: a second unit of the same build beside the first, its base 400 µm further along
  x and y and 200 µm higher, its axes misaligned and coupled otherwise (a rotation of
  0.15 degrees about z, other couplings and curvatures of the same sizes), with the
  hysteresis, creep and thermal drift of the first. Its travel overlaps m1's in all but a
  0.4 mm band, so the two tips can meet almost anywhere.
- ``p1``: the positioner carrying the sample, a stick-slip X-Y stage as the thesis's: two
  axes, its z joint held at 0 (see :class:`~microcal.devices.held_axes.HeldAxes`), so it
  moves the sample over a surface of {G}, not through a volume. Its board is the sample's
  marker; a point on the sample is a fixed offset from it. Mounted turned by 0.3 degrees
  about z and tilted by 0.1 degrees about x against the cameras' frame (30 µm and 10 µm
  over its 6 mm), with scale errors of 0.04 %, a bow of up to 3.6 µm in z over the travel
  and hysteresis of 0.2-0.25 µm.

The simulator shows one board at a time (:class:`~microcal.sim.platforms.Scene`): that of
the device that moved last, or the one asked for.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from ..kinematics.models import KinematicModel
from ..kinematics.terms import JOINTS, polynomial_terms, terms_without
from .kinematics import TrueKinematics

__all__ = ["positioner_kinematics", "second_manipulator_kinematics"]


def _static(linear: np.ndarray, quadratic: dict[tuple[int, str], float], base_um: list[float],
            held_um: dict[str, float] | None = None) -> KinematicModel:  # fmt: skip
    held = held_um or {}
    terms = polynomial_terms(JOINTS, 2)
    names = [t.name for t in terms]
    coef = np.zeros((3, len(terms)))
    for j, joint in enumerate(JOINTS):
        coef[:, names.index(joint)] = linear[:, j]
    for (axis, name), value in quadratic.items():
        coef[axis, names.index(name)] = value
    coef[:, names.index("1")] = base_um
    kept = terms_without(terms, held)  # a held joint has no terms
    coef = coef[:, [terms.index(t) for t in kept]]
    terms = kept
    return KinematicModel(
        kind="polynomial", inputs=JOINTS, joints=JOINTS, terms=terms, coefficients=coef,
        selected=coef != 0, covariance=np.zeros((3, len(terms), len(terms))),
        selection={"method": "truth"}, held_um=held,
    )  # fmt: skip


def second_manipulator_kinematics(first: TrueKinematics) -> TrueKinematics:
    """``m2``: ``first``'s error sources, its own static map (see the module docstring)."""
    a = np.radians(0.15)
    turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    linear = turn @ np.array(
        [[0.99985, 0.00060, 0.00030], [-0.00025, 1.00040, 0.00410], [0.00070, -0.00110, 1.00030]]
    )
    static = _static(
        linear,
        {(0, "dx*dy"): -9.0e-8, (1, "dx^2"): 6.0e-8, (2, "dz^2"): 1.2e-6, (2, "dy^2"): -4.0e-8},
        [1400.0, 1200.0, 500.0],
    )
    return dataclasses.replace(first, static=static)


def positioner_kinematics() -> TrueKinematics:
    """``p1``: the sample's positioner (see the module docstring)."""
    a, b = np.radians(0.3), np.radians(0.1)  # mounted turned about z and tilted about x
    turn = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    tilt = np.array([[1.0, 0, 0], [0, np.cos(b), -np.sin(b)], [0, np.sin(b), np.cos(b)]])
    linear = turn @ tilt @ np.diag([1.0004, 0.9996, 1.0])  # its z column is not used
    static = _static(
        linear,
        {(2, "dx^2"): -4.0e-7, (2, "dy^2"): 3.0e-7, (2, "dx*dy"): 2.0e-7, (0, "dy^2"): 1.0e-7},
        [2000.0, 1800.0, 1200.0],
        held_um={"dz": 0.0},
    )
    return TrueKinematics(
        static=static,
        hysteresis_um=np.array([0.25, 0.2, 0.3]),
        thermal_um_per_c=np.array([0.4, 0.3, 0.6]),
        reference_temperature_c=22.0,
        creep_fraction=5e-4,
        creep_tau_s=0.6,
    )
