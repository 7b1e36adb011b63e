"""Moves along a tool's approach axis: the targets of a move of D µm along it.

A patch or injection pipette enters the tissue along its own length: the manipulator's
approach axis is mounted along the pipette, tilted 20-40 degrees below the focal plane,
and a move "along the approach" must keep the tip on that line, whatever the other axes'
couplings (a straight move across tissue tears less of it).

**Which axis.** The direction used is the calibration's: the tip's move in {G} (on a
microscope, its frame {M}) per µm of the approach joint, the identified model's Jacobian
column of that joint at the present joints, normalised. It is measured (the model is
identified from tips measured in 3D over the working volume), it holds the joint's tilt,
the couplings and, for the polynomial model, how the direction changes over the travel.
The pipette's own axis as the camera sees it is not used: one camera sees its direction in
the image but not its tilt out of the focal plane (the tip's depth comes from the focus,
the shank's from nothing), so the tilt would be the user's nominal angle. On a rig whose
approach joint is mounted along the pipette (as patch manipulators are) the two agree to
the mounting's error.

:func:`approach_targets_um` is pure: from where the tip is, the axis and the distance, the
targets in {G}, a straight line cut into steps. :func:`plan_approach` adds the joints of two
ways there, open loop:

- ``path="joint"``: the approach joint alone travels (the others hold), each step as far as
  the model says takes the tip the step's distance along the axis. No joint goes back and
  forth (a lateral joint that reverses even by nanometres crosses its reversal error, a
  few tenths of a µm); the tip follows the joint's own path, which the model says bends off
  the straight line by :attr:`ApproachMove.bend_um`.
- ``path="line"``: the compensator's joints for each target (every joint may move; with a
  model's direction terms each arrives from below, so it may first go back 20 µm).

A :class:`~microcal.procedures.station.Station` moves the tip through either, and closes the
loop at the end when asked (visual servoing to the last target).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, check_number
from ..errors import InputError
from ..kinematics.models import KinematicModel

__all__ = [
    "APPROACH_JOINT",
    "ApproachMove",
    "approach_axis",
    "approach_targets_um",
    "joint_travel_um",
    "plan_approach",
]

#: The joint of a patch manipulator that is mounted along its pipette (its x axis).
APPROACH_JOINT = "dx"


@dataclass(frozen=True)
class ApproachMove:
    """A move along the approach axis, planned.

    Attributes
    ----------
    start_um : (3,) float
        Where the tip is taken to be at the start, {G} µm.
    axis : (3,) float
        Unit direction of the move in {G} (positive: the way the approach joint's positive
        travel moves the tip).
    distance_um : float
        Signed length of the move, µm.
    targets_um : (n, 3) float
        The targets in order; the last is ``start_um + distance_um * axis``.
    joint : str
        The approach joint (``dx``).
    joints_um : (n, 3) float
        The joints of the approach joint's own travel to each target (``path="joint"``; the
        other joints held); empty (0, 3) when not planned.
    bend_um : float
        How far the model puts the tip off the straight line along that travel, at most, µm.
    """

    start_um: FloatArray
    axis: FloatArray
    distance_um: float
    targets_um: FloatArray
    joint: str = APPROACH_JOINT
    joints_um: FloatArray = field(default_factory=lambda: np.zeros((0, 3)))
    bend_um: float = 0.0

    @property
    def elevation_deg(self) -> float:
        """The axis's angle to {G}'s x-y plane (a microscope's focal plane), degrees; positive
        when the tip rises as the joint travels forward."""
        return float(np.degrees(np.arcsin(np.clip(self.axis[2], -1.0, 1.0))))


def _joint_index(model: KinematicModel, joint: str) -> int:
    """The index of ``joint`` (``dx``, or the axis's name ``x``) among the model's joints."""
    if joint not in model.joints and f"d{joint}" in model.joints:
        joint = f"d{joint}"
    if joint not in model.joints:
        raise InputError(
            f"approach joint {joint!r}: the model's joints are {', '.join(model.joints)}"
        )
    return model.joints.index(joint)


def _inputs(model: KinematicModel, d_um: ArrayLike, extra: ArrayLike | None) -> FloatArray:
    """The model's inputs (k,): the joints, then its other inputs."""
    d = as_array(d_um, "d_um", (len(model.joints),))
    rest = np.zeros(0) if extra is None else np.asarray(extra, dtype=np.float64).ravel()
    if len(rest) != len(model.extra_inputs):
        raise InputError(
            f"extra: the model takes {len(model.extra_inputs)} inputs besides its joints "
            f"({', '.join(model.extra_inputs) or 'none'}), got {len(rest)}"
        )
    return np.concatenate([d, rest])


def approach_axis(
    model: KinematicModel,
    d_um: ArrayLike,
    extra: ArrayLike | None = None,
    joint: str = APPROACH_JOINT,
) -> FloatArray:
    """The unit direction (3,) in {G} in which joint ``joint`` moves the tip at joints
    ``d_um`` (3,), from the model's Jacobian; ``extra`` the model's other inputs (its
    approach directions, the temperature) in its order.

    Raises
    ------
    InputError
        ``joint`` is not one of the model's joints, or it does not move the tip.
    """
    k = _joint_index(model, joint)
    u = _inputs(model, d_um, extra)
    column = model.jacobian(u)[0][:, k]
    norm = float(np.linalg.norm(column))
    if not np.isfinite(norm) or norm < 1e-6:
        raise InputError(f"approach joint {joint!r}: the model says it does not move the tip")
    out: FloatArray = column / norm
    return out


def approach_targets_um(
    start_um: ArrayLike, axis: ArrayLike, distance_um: float, step_um: float | None = None
) -> FloatArray:
    """The targets (n, 3) of a move of ``distance_um`` from ``start_um`` (3,) along the
    unit ``axis`` (3,), in steps of at most ``step_um`` (None: one step), the last exactly
    at the distance.

    Raises
    ------
    InputError
        A distance that is not a finite number, a step that is not positive, or an axis
        that is not a unit vector.
    """
    start = as_array(start_um, "start_um", (3,))
    u = as_array(axis, "axis", (3,))
    check_number("distance_um", distance_um)
    if not abs(float(np.linalg.norm(u)) - 1.0) < 1e-9:
        raise InputError("axis: expected a unit vector")
    n = 1
    if step_um is not None:
        check_number("step_um", step_um, above=0)
        n = max(1, int(np.ceil(abs(distance_um) / step_um - 1e-9)))
    s = float(distance_um) * np.arange(1, n + 1) / n
    out: FloatArray = start[None, :] + s[:, None] * u[None, :]
    return out


def joint_travel_um(
    model: KinematicModel,
    d_um: ArrayLike,
    axis: ArrayLike,
    distances_um: ArrayLike,
    extra: ArrayLike | None = None,
    joint: str = APPROACH_JOINT,
) -> tuple[FloatArray, FloatArray]:
    """The joints (n, 3) that take the tip ``distances_um`` (n,) along the unit ``axis`` (3,)
    from joints ``d_um`` (3,) by the approach joint alone, and how far off the line through
    the model's tip at ``d_um`` along ``axis`` each puts the tip (n,), µm.

    Each joint value solves ``(p(d + t e) - p(d)) . axis = s`` for ``t`` by Newton's method
    on the model (a few steps: the model is nearly linear along one joint).

    Raises
    ------
    InputError
        A joint the model lacks, or one that does not move the tip along ``axis``.
    """
    k = _joint_index(model, joint)
    u0 = _inputs(model, d_um, extra)
    a = as_array(axis, "axis", (3,))
    s = np.atleast_1d(np.asarray(distances_um, dtype=np.float64))
    p0 = model.predict_um(u0)[0]
    joints = np.zeros((len(s), len(model.joints)))
    off = np.zeros(len(s))
    t = 0.0
    for n, target in enumerate(s):
        u = u0.copy()
        for _ in range(8):
            u[k] = u0[k] + t
            along = float((model.predict_um(u)[0] - p0) @ a)
            rate = float(model.jacobian(u)[0][:, k] @ a)
            if abs(rate) < 1e-6:
                raise InputError(
                    f"approach joint {joint!r}: it does not move the tip along the axis"
                )
            dt = (target - along) / rate
            t += dt
            if abs(dt * rate) < 1e-9:
                break
        u[k] = u0[k] + t
        moved = model.predict_um(u)[0] - p0
        joints[n] = u[: len(model.joints)]
        off[n] = float(np.linalg.norm(moved - (moved @ a) * a))
    return joints, off


def plan_approach(
    model: KinematicModel,
    d_um: ArrayLike,
    distance_um: float,
    *,
    start_um: ArrayLike | None = None,
    extra: ArrayLike | None = None,
    step_um: float | None = None,
    joint: str = APPROACH_JOINT,
) -> ApproachMove:
    """The move of ``distance_um`` along the approach axis at joints ``d_um`` (3,): the
    axis, the targets and the approach joint's own travel to them (module docstring).

    The start is ``start_um`` where given (the tip as measured), else where the model puts
    the tip for ``d_um`` (the open loop's own reference: the move is then the model's
    difference between two of its predictions, so its constant errors cancel).
    """
    axis = approach_axis(model, d_um, extra, joint)
    start: FloatArray = (
        model.predict_um(_inputs(model, d_um, extra))[0]
        if start_um is None
        else as_array(start_um, "start_um", (3,))
    )
    targets = approach_targets_um(start, axis, distance_um, step_um)
    distances = (targets - start) @ axis
    joints, off = joint_travel_um(model, d_um, axis, distances, extra, joint)
    name = model.joints[_joint_index(model, joint)]
    return ApproachMove(start, axis, float(distance_um), targets, name, joints,
                        float(off.max(initial=0.0)))  # fmt: skip
