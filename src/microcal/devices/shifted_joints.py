"""A manipulator whose joints are counted from a chosen origin.

microcal's evaluation (thesis 5.3, ISO 9283) takes the zero joints as home and its poses as
displacements from there. On a microscope the tip is seen only near where the user brought
it into the field, far from the travel's zero: :class:`ShiftedJoints` presents the device
with its joints counted from that point, so that home is in view and every procedure runs
unchanged. Commands, positions and soft limits are all shifted alike.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from .base import Manipulator
from .wrapped_manipulator import WrappedManipulator

__all__ = ["ShiftedJoints"]


class ShiftedJoints(WrappedManipulator):
    """``device`` with its joints counted from ``origin_um`` (n_axes,), µm."""

    def __init__(self, device: Manipulator, origin_um: ArrayLike) -> None:
        self.origin_um: FloatArray = as_array(origin_um, "origin_um", (device.n_axes,))
        super().__init__(device, device.axes, device.limits_um - self.origin_um[:, None])

    def _move(self, d_um: FloatArray) -> None:
        self.device.move_to_um(np.asarray(d_um, dtype=np.float64) + self.origin_um)

    def _position_um(self) -> FloatArray:
        out: FloatArray = self.device.position_um() - self.origin_um
        return out
