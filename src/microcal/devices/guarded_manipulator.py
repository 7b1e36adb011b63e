"""A manipulator with a stop that holds: after :meth:`GuardedManipulator.halt`, no move.

The station page's stop control calls :meth:`~GuardedManipulator.halt` from whichever thread
serves it while a move runs in another: the device is told to stop at once, and every move
asked for afterwards (the rest of a closed loop, the second leg of an approach from below)
is refused with :class:`~microcal.errors.DeviceError` until :meth:`~GuardedManipulator.resume`.
"""

from __future__ import annotations

import threading

from .._validation import FloatArray
from ..errors import DeviceError
from .base import Manipulator
from .wrapped_manipulator import WrappedManipulator

__all__ = ["HALTED", "GuardedManipulator"]

#: The message of a move refused after a stop.
HALTED = "stopped: the stop control was pressed; nothing moves until the next go"


class GuardedManipulator(WrappedManipulator):
    """``inner`` with a stop that holds (see the module docstring).

    Parameters
    ----------
    inner : Manipulator
        The device; closing this one closes it. Its name, axes, soft limits and identity are
        this one's.
    """

    def __init__(self, inner: Manipulator) -> None:
        super().__init__(inner, inner.axes, inner.limits_um)
        self._halted = threading.Event()

    @property
    def halted(self) -> bool:
        """True from :meth:`halt` until :meth:`resume`."""
        return self._halted.is_set()

    def halt(self) -> None:
        """Refuse every further move, then stop the device now."""
        self._halted.set()
        self.device.stop()

    def resume(self) -> None:
        """Accept moves again."""
        self._halted.clear()

    def _move(self, d_um: FloatArray) -> None:
        if self._halted.is_set():
            raise DeviceError(f"{self.name}: {HALTED}")
        self.device.move_to_um(d_um)

    def _position_um(self) -> FloatArray:
        return self.device.position_um()
