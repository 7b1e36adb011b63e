"""Compensation of one position: the joints that put the end-effector there, and how sure."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import InputError
from ..kinematics.extra_inputs import by_symbol, fixed_approach_values, values_for
from ..kinematics.manipulator_calibration import ManipulatorCalibration

__all__ = ["Solution", "solve_position"]


@dataclass(frozen=True)
class Solution:
    """Joint commands for a target and what to know about them.

    Attributes
    ----------
    d_um : (3,) float
        Joint commands, µm.
    residual_um : (3,) float
        model(d) - target, µm.
    outside_range : (3, 2) float or None
        The joint range the model was identified on, when ``d_um`` leaves it (the model
        extrapolates there); None otherwise.
    approach_from_below : bool
        The model has approach-direction terms and the joints are solved for arriving moving
        up (+1), as :class:`~microcal.control.feedforward.FeedForward` drives them.
    """

    d_um: FloatArray
    residual_um: FloatArray
    outside_range: FloatArray | None
    approach_from_below: bool = False


def solve_position(
    calibration: ManipulatorCalibration,
    target_um: ArrayLike,
    values: Mapping[str, float] | None = None,
    *,
    limits_um: ArrayLike | None = None,
) -> Solution:
    """The compensator for one target position in {G}.

    Parameters
    ----------
    target_um : (3,) float
    values : mapping of name -> value, optional
        Values of the model's extra inputs by registry name (``{"temperature": 23.0}``).
    limits_um : (3, 2) float, optional
        Soft limits; a target needing joints outside raises LimitError.
    """
    target = as_array(target_um, "position", (3,))
    symbols = calibration.model.extra_inputs
    unused = sorted(set(values or {}) - {by_symbol(s).name for s in symbols})
    if unused:
        raise InputError(
            f"--{unused[0]}: the model of {calibration.name!r} has no {unused[0]} input"
            + (f" (its extra inputs: {list(symbols)})" if symbols else "")
        )
    approach = fixed_approach_values(symbols)  # arriving moving up, as FeedForward drives
    extra = values_for(symbols, dict(values or {}) | approach)
    d = calibration.joints_for(target, extra=extra, limits_um=limits_um)[0]
    u = d if extra is None else np.concatenate([d, extra[0]])
    residual = calibration.predict_um(u)[0] - target
    return Solution(d, residual, calibration.outside_joint_range_um(d), bool(approach))
