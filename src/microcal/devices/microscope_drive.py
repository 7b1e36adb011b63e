"""The callables a one-camera procedure takes, made from a rig's devices.

The one-camera procedures (the scope calibration, the tip's depth from focus, the one-camera
acquisition and probe) take ``move_focus(z_um)``, ``move_stage(xy_um)`` and ``grab()``:
:class:`MicroscopeDrive` makes them from a :class:`~microcal.devices.rig.Rig`'s
``microscope`` (the X-Y stage and focus as joints x, y, z) and one of its cameras. Each move
moves the stage or the focus alone where the device can (``move_stage_um``,
``move_focus_um``), else commands all three joints, the two it does not change at their last
command (read once from the device when the drive is made); then it waits until the device
reports stopped. A grab is a region frame where the camera gives one
(:func:`~microcal.vision.lazy_frame.grab_frame`).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..vision.lazy_frame import RegionFrame, grab_frame
from .base import Camera, Clock, Manipulator

__all__ = ["MicroscopeDrive"]


class MicroscopeDrive:
    """Focus, stage and camera of a one-camera rig as callables (module docstring).

    Parameters
    ----------
    microscope : Manipulator
        Joints x, y (the stage) and z (the focus), µm.
    camera : Camera
    clock : Clock
    """

    def __init__(self, microscope: Manipulator, camera: Camera, clock: Clock) -> None:
        self.microscope = microscope
        self.camera = camera
        self.clock = clock
        self._command: FloatArray = np.asarray(microscope.position_um(), dtype=np.float64).copy()

    @property
    def focus_um(self) -> float:
        """The focus's last command, µm."""
        return float(self._command[2])

    @property
    def stage_um(self) -> FloatArray:
        """The stage's last command, (2,) µm."""
        out: FloatArray = self._command[:2].copy()
        return out

    def _go(self, target: FloatArray, alone: str) -> None:
        move_alone = getattr(self.microscope, alone, None)
        if callable(move_alone):  # the stage or the focus alone
            move_alone(target[:2] if alone == "move_stage_um" else float(target[2]))
        else:
            self.microscope.move_to_um(target)
        self._command = target
        self.microscope.wait_until_stopped(self.clock)

    def move_focus(self, z_um: float) -> None:
        """Move the focus to ``z_um`` and wait until it has stopped."""
        self._go(np.array([self._command[0], self._command[1], float(z_um)]), "move_focus_um")

    def move_stage(self, xy_um: ArrayLike) -> None:
        """Move the stage to ``xy_um`` (2,) µm and wait until it has stopped."""
        xy = as_array(xy_um, "xy_um", (2,))
        self._go(np.array([xy[0], xy[1], self._command[2]]), "move_stage_um")

    def grab(self) -> RegionFrame:
        """One frame of the camera (a region frame)."""
        return grab_frame(self.camera)

    def grab_at_focus(self, z_um: float) -> RegionFrame:
        """Move the focus to ``z_um`` and grab a frame."""
        self.move_focus(z_um)
        return self.grab()
