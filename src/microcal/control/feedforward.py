"""Feed-forward control (thesis Fig 2.5, 4.4, 4.5): move the end-effector to a position in {G}.

:class:`FeedForward` gives any :class:`Manipulator` a ``move_to_position_um(p)``: the joints
come from a compensator of the identified model (the matrix compensator, Eq 4.16, or the
optimal one, Eq 4.17-4.19), are checked against the manipulator's soft limits (a target
outside raises :class:`LimitError` and nothing moves), then commanded.

A model with approach-direction terms (``sx, sy, sz``: reversal error) is driven with a
fixed approach: every joint first goes to :data:`APPROACH_UM` below its command, then up to
it, so each joint arrives moving up and the terms are evaluated at +1.
:func:`extra_inputs_reader` reads the other extra inputs (the temperature) from the rig's
sensors at every move.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..devices.base import Clock, Manipulator
from ..errors import DegenerateDataError, InputError, LimitError
from ..kinematics.compensators import Compensator
from ..kinematics.extra_inputs import by_symbol, fixed_approach_values, values_for
from ..kinematics.models import KinematicModel

__all__ = ["APPROACH_UM", "FeedForward", "extra_inputs_reader", "has_approach_terms"]

#: The last stretch of a fixed approach: each joint comes up this far to its command, µm.
APPROACH_UM = 20.0


def has_approach_terms(model: KinematicModel) -> bool:
    """Whether the model has inputs for the joints' approach directions."""
    return bool(fixed_approach_values(model.extra_inputs))


def extra_inputs_reader(
    model: KinematicModel, sensors: Mapping[str, Callable[[], float]] | None
) -> Callable[[], FloatArray] | None:
    """A callable giving the model's extra inputs, in the model's order, at each move.

    Sensors are read by registry name; an approach direction is +1 (the fixed approach of
    :class:`FeedForward`). None for a model without extra inputs.

    Raises
    ------
    InputError
        The model needs a sensor the rig lacks.
    """
    symbols = model.extra_inputs
    if not symbols:
        return None
    approach = fixed_approach_values(symbols)
    read = dict(sensors or {})
    sensed = [by_symbol(s).name for s in symbols if by_symbol(s).name not in approach]
    missing = [n for n in sensed if n not in read]
    if missing:
        raise InputError(f"the model needs {missing} but the rig has no such sensor")

    def values() -> FloatArray:
        out = values_for(symbols, {n: float(read[n]()) for n in sensed} | approach)
        assert out is not None
        row: FloatArray = out[0]
        return row

    return values


class FeedForward:
    """A manipulator driven in {G} through a compensator.

    Parameters
    ----------
    manipulator : Manipulator
    model : KinematicModel
        The identified model of this manipulator.
    method : {"optimal", "matrix"}
        Solve the whole model (optimal) or only its linear part (matrix, Eq 4.16).
    extra : callable () -> extra inputs, optional
        For models with inputs besides the joints (the temperature): read at every move.
    clock : Clock, optional
        Needed for a model with approach-direction terms: the fixed approach waits for its
        first move to end.
    """

    def __init__(
        self,
        manipulator: Manipulator,
        model: KinematicModel,
        method: Literal["optimal", "matrix"] = "optimal",
        extra: Callable[[], ArrayLike] | None = None,
        clock: Clock | None = None,
    ) -> None:
        self.manipulator = manipulator
        self.model = model
        self.method = method
        self.extra = extra
        self._compensator = Compensator(model, manipulator.limits_um)
        self.approach_um = APPROACH_UM if has_approach_terms(model) else 0.0
        if self.approach_um and clock is None:
            raise InputError(
                "FeedForward: a model with approach-direction terms needs the clock (its fixed "
                "approach waits for the first move to end)"
            )
        self.clock = clock
        self._approach_symbols = {s for s in model.extra_inputs if fixed_approach_values([s])}

    def joints_for(self, p_um: ArrayLike) -> FloatArray:
        """Joint commands for one position in {G}, (3,) µm; checked against the soft limits."""
        return self._joints(p_um, None if self.extra is None else self.extra())

    def _joints(self, p_um: ArrayLike, extra: ArrayLike | None) -> FloatArray:
        p = as_array(p_um, "p_um", (3,))
        if self.method == "matrix":
            return np.asarray(self._compensator.linear(p, extra=extra)[0], dtype=np.float64)
        result = self._compensator.solve(p, extra=extra)
        if not result.converged[0]:
            raise DegenerateDataError(
                f"{self.manipulator.name}: the model has no solution for "
                f"{np.round(p, 3).tolist()} µm (residual {result.residual_um[0]:.3g} µm); "
                f"nothing was moved"
            )
        return np.asarray(result.d_um[0], dtype=np.float64)

    def home_um(self) -> FloatArray:
        """Where the model puts the end-effector at zero joints, (3,) µm in {G}: P_B, or for
        a model with sensed inputs (the temperature) its prediction there at their values now
        (its constant alone is at 0 °C)."""
        sensed = [s for s in self.model.extra_inputs if s not in self._approach_symbols]
        if not sensed or self.extra is None:
            return self.model.p_base_um
        u = np.concatenate([self.model.rest_um, np.asarray(self.extra(), float)])
        out: FloatArray = self.model.predict_um(u)[0]
        return out

    def aim_um(self, p_um: ArrayLike) -> FloatArray:
        """Where the model puts the end-effector for the joints it commands for ``p_um``, (3,)
        µm in {G}: ``p_um`` itself, or for a device with held joints (an X-Y positioner) the
        nearest point of the surface it reaches."""
        p = as_array(p_um, "p_um", (3,))
        if not self.model.held_um:
            return p
        extra = None if self.extra is None else np.asarray(self.extra(), float).ravel()
        d = self._joints(p, extra)  # the inputs read once, for the joints and the prediction
        u = d if extra is None else np.concatenate([d, extra])
        out: FloatArray = self.model.predict_um(u)[0]
        return out

    def move_to_position_um(self, p_um: ArrayLike) -> FloatArray:
        """Move the end-effector to ``p_um`` in {G}; returns the joints commanded.

        Raises
        ------
        LimitError
            The joints would leave the soft limits (nothing moves).
        DegenerateDataError
            The model has no solution there (nothing moves).
        """
        d = self.joints_for(p_um)
        if self.approach_um:
            low = self.manipulator.limits_um[:, 0]
            start = self.manipulator.below_um(d, self.approach_um)
            if np.any(start < low):
                raise LimitError(
                    f"{self.manipulator.name}: joints {np.round(d, 3).tolist()} µm are less than "
                    f"{self.approach_um:g} µm above the lower limits {low.tolist()}: the model's "
                    "direction terms need each joint to arrive moving up; nothing was moved"
                )
            self.manipulator.move_to_um(start)
            assert self.clock is not None
            self.manipulator.wait_until_stopped(self.clock)
        self.manipulator.move_to_um(d)
        return d
