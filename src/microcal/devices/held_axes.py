"""A device with fewer than three axes presented as the three joints x, y, z.

microcal's procedures, models and files speak of three joints ``dx, dy, dz``. A two-axis X-Y
positioner (the thesis's section 2.4 carries one under the sample) has no z drive; it joins
them as a manipulator whose missing joints are **held**: their soft limits are the one value
they are held at (0 µm), a command must give them that value, and its position reads it.
Identification leaves a held joint out of the model, and a compensator solves for the others
(see :class:`~microcal.kinematics.models.KinematicModel`).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from .._validation import FloatArray
from ..errors import InputError
from .base import Manipulator
from .wrapped_manipulator import WrappedManipulator

__all__ = ["AXES", "HeldAxes", "axes_in_order", "with_three_joints"]

#: The three joints every procedure speaks of, in order.
AXES: tuple[str, ...] = ("x", "y", "z")


def axes_in_order(axes: Sequence[str]) -> bool:
    """Whether ``axes`` are some of x, y, z, in that order (``x, y`` for an X-Y stage)."""
    return bool(axes) and list(axes) == [a for a in AXES if a in axes]


class HeldAxes(WrappedManipulator):
    """A manipulator of some of the axes x, y, z as one of all three, the others held at 0.

    Parameters
    ----------
    device : Manipulator
        Its axes a subset of ``x, y, z`` in that order (``("x", "y")`` for an X-Y stage).

    Raises
    ------
    InputError
        Axes other than a subset of x, y, z in order.
    """

    def __init__(self, device: Manipulator) -> None:
        if not axes_in_order(device.axes):
            raise InputError(
                f"{device.name}: expected axes among x, y, z in that order, got {list(device.axes)}"
            )
        self._index = [AXES.index(a) for a in device.axes]
        limits = np.zeros((3, 2))
        limits[self._index] = device.limits_um
        super().__init__(device, AXES, limits)

    def _move(self, d_um: FloatArray) -> None:
        self.device.move_to_um(d_um[self._index])

    def _position_um(self) -> FloatArray:
        out = np.zeros(3)
        out[self._index] = self.device.position_um()
        return out


def with_three_joints(device: Manipulator) -> Manipulator:
    """``device`` itself when its axes are x, y, z; else wrapped in :class:`HeldAxes`."""
    return device if device.axes == AXES else HeldAxes(device)
