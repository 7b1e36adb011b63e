"""Run planning: the joint commands an acquisition will visit, from the rig's own limits.

A plan is one of the generated designs of :mod:`microcal.kinematics.designs` over the
manipulator's soft limits (checked to identify a model), an evaluation trajectory (checked
against the limits only), or commands the user gives. What the plan records reproduces it:
``make_design(plan.kind, plan.poses, low, high, plan.seed)`` over the same limits gives the
same commands.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array, check_limits
from ..errors import InputError
from ..kinematics.designs import DESIGNS, check_design, make_design
from ..thesis.experiment import TABLE_5_2_POSES_UM
from .evaluation import decoupling_path, iso_cube_poses

__all__ = [
    "DESIGN_CHOICES",
    "MAX_DESIGN_POSES",
    "MIN_DESIGN_POSES",
    "POLYNOMIAL_POSES",
    "TRAJECTORIES",
    "RunPlan",
    "check_poses",
    "plan_run",
    "trajectory",
]

#: Evaluation trajectories an acquisition can follow (thesis Table 5-2, Fig 5.5, ISO 9283).
TRAJECTORIES = ("table-5-2", "decoupling", "iso-cube")
#: Every named design; anything else is a CSV file of commands.
DESIGN_CHOICES = (*DESIGNS, *TRAJECTORIES)
#: A generated design identifies a model fitted on about two thirds of its poses and
#: validated on the rest: the matrix model (4 terms per axis) needs 12 poses, the polynomial
#: model (10 terms per axis) about 30 (:data:`POLYNOMIAL_POSES`; the thesis used 170).
MIN_DESIGN_POSES = 12
POLYNOMIAL_POSES = 30
#: More poses than this is a typing slip (at the thesis's 30 s settle, about a week).
MAX_DESIGN_POSES = 20_000


@dataclass(frozen=True)
class RunPlan:
    """The commands of a run and what generated them.

    Attributes
    ----------
    kind : str
        A design of :data:`DESIGN_CHOICES`, or ``"file"`` for given commands.
    seed : int
        The design's seed.
    d_um : (N, k) float
        Joint commands, µm, in visiting order.
    low_um, high_um : (k,) float, optional
        The box a generated design covers.
    """

    kind: str
    seed: int
    d_um: FloatArray
    low_um: FloatArray | None = None
    high_um: FloatArray | None = None

    @property
    def poses(self) -> int:
        """Number of poses."""
        return int(self.d_um.shape[0])

    def design_record(self) -> dict[str, object]:
        """The ``design`` object of run.json."""
        record: dict[str, object] = {"kind": self.kind, "poses": self.poses, "seed": self.seed}
        if self.low_um is not None and self.high_um is not None:
            record |= {"low_um": self.low_um.tolist(), "high_um": self.high_um.tolist()}
        return record


def check_poses(design: str, poses: int) -> None:
    """Refuse a pose count a generated design cannot identify a model from, or absurd.

    Raises
    ------
    InputError
        Fewer than :data:`MIN_DESIGN_POSES` or more than :data:`MAX_DESIGN_POSES`.
    """
    if not MIN_DESIGN_POSES <= poses <= MAX_DESIGN_POSES:
        raise InputError(
            f"poses: expected {MIN_DESIGN_POSES} to {MAX_DESIGN_POSES} for a {design} "
            f"design (the matrix model needs {MIN_DESIGN_POSES} to fit and validate, the "
            f"polynomial model about {POLYNOMIAL_POSES}; the thesis used 170), got {poses}"
        )


def trajectory(name: str, limits_um: ArrayLike) -> FloatArray:
    """An evaluation trajectory's joint commands within a rig's limits, (N, 3) µm.

    ``table-5-2`` and ``decoupling`` are the thesis's commands as published; ``iso-cube`` is
    ISO 9283's P1-P5 in the cube spanned by the soft limits.
    """
    lim = as_array(limits_um, "limits_um", (3, 2))
    if name == "table-5-2":
        return TABLE_5_2_POSES_UM.copy()
    if name == "decoupling":
        return decoupling_path()[0]
    if name == "iso-cube":
        return iso_cube_poses(lim[:, 0], lim[:, 1])
    raise InputError(f"design: expected one of {list(DESIGN_CHOICES)}, got {name!r}")


def plan_run(
    design: str,
    poses: int,
    seed: int,
    limits_um: ArrayLike,
    *,
    axes: tuple[str, ...] = ("x", "y", "z"),
    commands_um: ArrayLike | None = None,
) -> RunPlan:
    """Plan a run on a manipulator with the given soft limits.

    Parameters
    ----------
    design : str
        A generated design (``random``, ``sobol``, ``lhs``, ``grid``) over the limits, an
        evaluation trajectory (:data:`TRAJECTORIES`), or ``"file"`` with ``commands_um``.
    poses : int
        Poses of a generated design.
    seed : int
        Seed of a generated design.
    limits_um : (k, 2) float
        The manipulator's soft limits.
    commands_um : (N, k) float, optional
        The commands of a ``"file"`` design.

    Raises
    ------
    LimitError
        A command outside the limits (nothing has moved).
    DegenerateDataError
        A design that cannot identify a model (an axis barely moved, axes moved together).
    """
    lim = as_array(limits_um, "limits_um", (len(axes), 2))
    if design in DESIGNS:
        check_poses(design, poses)
        d = make_design(design, poses, lim[:, 0], lim[:, 1], seed)
        return RunPlan(design, seed, check_design(d, lim, axes), lim[:, 0], lim[:, 1])
    if design in TRAJECTORIES:  # for evaluation: only the limits matter
        d = trajectory(design, lim)
        return RunPlan(design, seed, check_limits(d, lim, axes=axes))
    if design == "file" and commands_um is not None:
        d = np.asarray(commands_um, dtype=np.float64)
        return RunPlan("file", seed, check_design(d, lim, axes))
    raise InputError(
        f"design: expected one of {list(DESIGN_CHOICES)} or a CSV file, got {design!r}"
    )
