"""The simulated stick-slip micromanipulator (a :class:`Manipulator` backend).

Each joint travels at ``speed_um_s`` to its target; the device's own position loop reports
"moving" until ``loop_settle_s`` after the last joint arrived. The end-effector's true
position follows :class:`TrueKinematics` (static errors, hysteresis from each joint's
approach direction, thermal drift) and keeps creeping after the move with the kinematics'
time constant. The position readout has its own sensor noise. Optionally (``motion``,
:mod:`~microcal.sim.motion`) a move ends on the joint's step grid and off by a random
scatter, and with the kinematics' ``play`` the reversal error remembers how far each joint
travelled since it last turned. Faults are injected at the
given rates: a move the controller refuses (:class:`MoveError`) and a command that times out
(:class:`DeviceTimeoutError`); neither moves anything.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, check_number
from ..devices.base import Clock, Manipulator
from ..errors import DeviceTimeoutError, MoveError
from .kinematics import TrueKinematics
from .motion import MotionNoise

__all__ = ["ManipulatorFaults", "SimManipulator", "joints_travelled_um"]


def joints_travelled_um(
    start_um: FloatArray, target_um: FloatArray, speed_um_s: float, elapsed_s: float
) -> FloatArray:
    """Joints moving from ``start_um`` to ``target_um`` (3,), each at ``speed_um_s``, after
    ``elapsed_s`` (negative counts as 0), µm."""
    delta = target_um - start_um
    travelled = np.minimum(np.abs(delta), speed_um_s * max(elapsed_s, 0.0))
    out: FloatArray = start_um + np.sign(delta) * travelled
    return out


@dataclass(frozen=True)
class ManipulatorFaults:
    """Fault rates per command (0 = never)."""

    move_failure_rate: float = 0.0
    timeout_rate: float = 0.0

    def __post_init__(self) -> None:
        for f in dataclasses.fields(self):
            check_number(f.name, getattr(self, f.name), low=0, high=1)


class SimManipulator(Manipulator):
    """A simulated Cartesian manipulator with true kinematics, timing, creep and faults.

    Parameters
    ----------
    truth : TrueKinematics
    clock : Clock
        Usually a :class:`SimClock`.
    rng : numpy.random.Generator
        For sensor noise and faults.
    limits_um : (3, 2) float
        Soft travel limits per joint; a joint whose limits are one value is held there (a
        two-axis X-Y positioner's z) and reads it without noise.
    speed_um_s : float
        Joint speed while moving (default 2000 µm/s).
    loop_settle_s : float
        The device's own position loop settles this long after arrival (default 0.4 s).
    sensor_noise_um : float
        Standard deviation of the position readout (default 0.05 µm).
    temperature_c : float
        Ambient temperature at time zero (default: the kinematics' reference).
    temperature_drift_c_per_h : float
        Linear drift of the ambient temperature (default 0).
    temperature_swing_c, temperature_period_h, temperature_phase : float
        A periodic swing of the ambient temperature (a room's air conditioning cycling):
        amplitude (default 0), period and phase.
    faults : ManipulatorFaults
    motion : MotionNoise, optional
        Step quantisation and scatter of each move (none by default).
    motion_rng : numpy.random.Generator, optional
        The scatter's own stream (so that the sensor noise and faults draw as without it);
        needed with a ``motion`` that scatters.
    """

    def __init__(
        self,
        truth: TrueKinematics,
        clock: Clock,
        rng: np.random.Generator,
        *,
        name: str = "m1",
        limits_um: ArrayLike = ((-500.0, 8500.0), (-500.0, 8500.0), (-500.0, 5300.0)),
        speed_um_s: float = 2000.0,
        loop_settle_s: float = 0.4,
        sensor_noise_um: float = 0.05,
        temperature_c: float | None = None,
        temperature_drift_c_per_h: float = 0.0,
        faults: ManipulatorFaults | None = None,
        temperature_swing_c: float = 0.0,
        temperature_period_h: float = 1.0,
        temperature_phase: float = 0.0,
        motion: MotionNoise | None = None,
        motion_rng: np.random.Generator | None = None,
    ) -> None:
        super().__init__(name, ("x", "y", "z"), limits_um)
        self.truth = truth
        #: Which unit this is where a preset draws each seed's kinematics ("" where not).
        self.unit = ""
        self.clock = clock
        self.rng = rng
        self.speed_um_s = float(speed_um_s)
        self.loop_settle_s = float(loop_settle_s)
        self.sensor_noise_um = float(sensor_noise_um)
        self.temperature_c0 = (
            truth.reference_temperature_c if temperature_c is None else temperature_c
        )
        self.temperature_drift_c_per_h = float(temperature_drift_c_per_h)
        self.temperature_swing_c = float(temperature_swing_c)
        self.temperature_period_h = float(temperature_period_h)
        self.temperature_phase = float(temperature_phase)
        self.faults = faults or ManipulatorFaults()
        self._start = np.clip(np.zeros(3), self.limits_um[:, 0], self.limits_um[:, 1])
        self._target = self._start.copy()
        self._t0 = clock.now_s()
        self._t_arrive = self._t0
        #: When the last move was sent, s (``-inf`` until the first one).
        self.last_move_s = -np.inf
        self._step = np.zeros(3)
        self._signs = np.ones(3)
        #: A change of the device since it was calibrated (tests of ``microcal check``): the
        #: end-effector shifted in {G} (a re-mounted device, an exchanged tool), µm ...
        self.mount_offset_um = np.zeros(3)
        #: ... and each joint's scale (1: as calibrated; 1.002: moves 0.2 % further).
        self.joint_scale = np.ones(3)
        self.motion = motion if motion is not None and motion.active else None
        self.motion_rng = motion_rng or np.random.default_rng(0)
        play = truth.play
        self._play = None if play is None else play.start_state_um(self._start)

    @property
    def identity(self) -> str:
        """``simulated m1``: the simulator's manipulator, the same unit for every seed of a
        preset whose kinematics do not depend on it (the thesis's); ``simulated m1
        (population seed 3)`` where each seed is another unit (:attr:`unit`)."""
        return f"simulated {self.name}" + (f" ({self.unit})" if self.unit else "")

    # --- the device protocol -------------------------------------------------------------
    def _fault(self, what: str) -> None:
        if self.faults.timeout_rate and self.rng.random() < self.faults.timeout_rate:
            raise DeviceTimeoutError(f"{self.name}: no answer to {what} within the timeout")

    def _move(self, d_um: FloatArray) -> None:
        self._fault("the move command")
        if self.faults.move_failure_rate and self.rng.random() < self.faults.move_failure_rate:
            raise MoveError(f"{self.name}: the controller refused the move (simulated fault)")
        now = self.clock.now_s()
        current = self.joints_um(now)
        step = d_um - current
        self._signs = np.where(step > 0, 1.0, np.where(step < 0, -1.0, self._signs))
        end = d_um.copy()
        if self.motion is not None:
            end = np.where(self.held, d_um, self.motion.end_um(current, d_um, self.motion_rng))
        if self._play is not None and self.truth.play is not None:
            self._play = self.truth.play.moved(self._play, end)
        self._start, self._target, self._t0 = current, end, now
        self.last_move_s = now
        self._step = step
        self._t_arrive = now + float(np.abs(step).max()) / self.speed_um_s

    def _position_um(self) -> FloatArray:
        self._fault("the position query")
        d = self.joints_um(self.clock.now_s())
        noise = self.rng.normal(0.0, self.sensor_noise_um, 3)
        out: FloatArray = d + np.where(self.held, 0.0, noise)
        return out

    def _is_moving(self) -> bool:
        self._fault("the status query")
        return self.clock.now_s() < self._t_arrive + self.loop_settle_s

    def _stop(self) -> None:
        now = self.clock.now_s()
        current = self.joints_um(now)
        self._step = current - self._start
        if self._play is not None and self.truth.play is not None:
            self._play = self.truth.play.moved(self._play, current)
        self._start = self._target = current
        self._t0 = self._t_arrive = now

    def _close(self) -> None:
        pass  # nothing to release: closing only marks the device closed

    # --- ground truth (tests and benchmarks only) ---------------------------------------
    def joints_um(self, t_s: float) -> FloatArray:
        """True joint positions at time ``t_s`` (each joint at its own constant speed)."""
        return joints_travelled_um(self._start, self._target, self.speed_um_s, t_s - self._t0)

    def approach_directions(self) -> FloatArray:
        """Each joint's effective approach direction now: the sign of its last move, or
        with play operators their sum in [-1, 1] at the joints' targets, (3,)."""
        play = self.truth.play
        if play is None or self._play is None:
            return self._signs.copy()
        return play.direction(self._play, self._target)

    def temperature_at(self, t_s: float) -> float:
        """Ambient temperature at time ``t_s``, °C."""
        h = t_s / 3600.0
        swing = self.temperature_swing_c * np.sin(
            2 * np.pi * h / self.temperature_period_h + self.temperature_phase
        )
        return float(self.temperature_c0 + self.temperature_drift_c_per_h * h + swing)

    def true_position_um(self, t_s: float | None = None) -> FloatArray:
        """True end-effector position in {G} at time ``t_s`` (now by default), (3,) µm."""
        t = self.clock.now_s() if t_s is None else t_s
        d = self.joints_um(t) * self.joint_scale
        signs = self._signs if self._play is None else self.approach_directions()
        p = self.truth.position_um(d, signs[None, :], self.temperature_at(t))[0]
        creep = self.truth.creep_um(self._step, t - self._t_arrive)[0]
        out: FloatArray = p + creep + self.mount_offset_um
        return out
