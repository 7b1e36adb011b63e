"""Feed-forward control (thesis Fig 2.5, 4.4, 4.5): move the end-effector to a position in {G}.

:class:`FeedForward` gives any :class:`Manipulator` a ``move_to_position_um(p)``: the joints
come from a compensator of the identified model (the matrix compensator, Eq 4.16, or the
optimal one, Eq 4.17-4.19), are checked against the manipulator's soft limits (a target
outside raises :class:`LimitError` and nothing moves), then commanded.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..devices.base import Manipulator
from ..errors import DegenerateDataError
from ..kinematics.compensators import Compensator
from ..kinematics.models import KinematicModel

__all__ = ["FeedForward"]


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
    """

    def __init__(
        self,
        manipulator: Manipulator,
        model: KinematicModel,
        method: Literal["optimal", "matrix"] = "optimal",
        extra: Callable[[], ArrayLike] | None = None,
    ) -> None:
        self.manipulator = manipulator
        self.model = model
        self.method = method
        self.extra = extra
        self._compensator = Compensator(model, manipulator.limits_um)

    def joints_for(self, p_um: ArrayLike) -> FloatArray:
        """Joint commands for one position in {G}, (3,) µm; checked against the soft limits."""
        p = as_array(p_um, "p_um", (3,))
        extra = None if self.extra is None else self.extra()
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
        self.manipulator.move_to_um(d)
        return d
