"""The simulated target stage: a precise X-Y-Z stage carrying the camera-calibration target.

Method (a) of the stereo calibration moves a target (the thesis's dot grid) by known steps.
This stage is that carrier: each joint travels at ``speed_um_s`` and its position loop
reports "moving" for ``loop_settle_s`` after arrival, like :class:`SimManipulator`, but its
kinematics are ideal (a closed-loop stage with linear encoders, whose errors are far below
the cameras' resolution), so the target sits exactly where it was sent. Its position readout
has its own sensor noise.

The stage at zero puts the target's frame on {G}, as in the demo's calibration. Which object
the cameras see is decided by the scene (:class:`~microcal.sim.platforms.Scene`): the target
while the stage was moved more recently than the manipulator (an operator put the target in
and the gripper's board out of view), the board otherwise.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..devices.base import Clock, Manipulator
from .manipulator import joints_travelled_um

__all__ = ["SimStage"]


class SimStage(Manipulator):
    """A precise Cartesian stage, positions in µm (a :class:`Manipulator` backend).

    Parameters
    ----------
    clock : Clock
    rng : numpy.random.Generator
        Source of the readout noise.
    name : str
    limits_um : (3, 2) array_like
        Soft limits per axis, µm.
    speed_um_s, loop_settle_s, sensor_noise_um : float
        Joint speed, settle time of the position loop and readout noise (standard deviation).
    """

    def __init__(
        self,
        clock: Clock,
        rng: np.random.Generator,
        *,
        name: str = "stage",
        limits_um: ArrayLike = ((-5000.0, 5000.0), (-5000.0, 5000.0), (-5000.0, 5000.0)),
        speed_um_s: float = 2000.0,
        loop_settle_s: float = 0.2,
        sensor_noise_um: float = 0.005,
    ) -> None:
        super().__init__(name, ("x", "y", "z"), limits_um)
        self.clock = clock
        self.rng = rng
        self.speed_um_s = float(speed_um_s)
        self.loop_settle_s = float(loop_settle_s)
        self.sensor_noise_um = float(sensor_noise_um)
        self._start = np.zeros(3)
        self._target = np.zeros(3)
        self._t0 = clock.now_s()
        self._t_arrive = self._t0
        #: When the last move was sent, s (``-inf`` until the first one).
        self.last_move_s = -math.inf

    def _move(self, d_um: FloatArray) -> None:
        now = self.clock.now_s()
        self._start = self.joints_um(now)
        self._target = d_um.copy()
        self._t0 = self.last_move_s = now
        self._t_arrive = now + float(np.abs(d_um - self._start).max()) / self.speed_um_s

    def _position_um(self) -> FloatArray:
        out: FloatArray = self.joints_um(self.clock.now_s()) + self.rng.normal(
            0.0, self.sensor_noise_um, 3
        )
        return out

    def _is_moving(self) -> bool:
        return self.clock.now_s() < self._t_arrive + self.loop_settle_s

    def _stop(self) -> None:
        now = self.clock.now_s()
        self._start = self._target = self.joints_um(now)
        self._t0 = self._t_arrive = now

    def _close(self) -> None:
        pass  # nothing to release

    def joints_um(self, t_s: float) -> FloatArray:
        """True position at time ``t_s``, (3,) µm (each joint at its own constant speed)."""
        return joints_travelled_um(self._start, self._target, self.speed_um_s, t_s - self._t0)
