"""A manipulator that presents another one: the base of microcal's device wrappers.

:class:`WrappedManipulator` keeps the wrapped device in ``device`` and hands it the status
query, the stop and the close, and takes its identity; a wrapper writes only what it
changes: the move and the position (with its own axes and soft limits where it shows the
device differently). The wrappers: :class:`~microcal.devices.held_axes.HeldAxes` (some
axes as all three), :class:`~microcal.devices.shifted_joints.ShiftedJoints` (joints counted
from an origin), :class:`~microcal.devices.guarded_manipulator.GuardedManipulator` (a stop
that holds).
"""

from __future__ import annotations

from numpy.typing import ArrayLike

from .base import Manipulator

__all__ = ["WrappedManipulator"]


class WrappedManipulator(Manipulator):
    """``device`` shown with ``axes`` and soft limits ``limits_um`` (n_axes, 2) µm; closing
    this one closes it.

    Subclasses write ``_move`` and ``_position_um``; the status query, the stop, the close
    and the identity are the device's.
    """

    def __init__(self, device: Manipulator, axes: tuple[str, ...], limits_um: ArrayLike) -> None:
        self.device = device
        super().__init__(device.name, axes, limits_um)

    @property
    def identity(self) -> str:
        """The wrapped device's identity."""
        return self.device.identity

    def _is_moving(self) -> bool:
        return self.device.is_moving()

    def _stop(self) -> None:
        self.device.stop()

    def _close(self) -> None:
        self.device.close()
