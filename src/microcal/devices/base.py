"""Base classes of the devices microcal drives: manipulators, cameras, clocks.

Every backend (the simulator, the SmarAct driver, a Micro-Manager bridge) subclasses these,
so procedures work with any of them. The base classes hold the behaviour that must be the
same everywhere: a move outside the soft limits raises :class:`LimitError` before anything is
sent; joint values are in µm; frames are numpy arrays.
"""

from __future__ import annotations

import abc
import time

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import FloatArray, as_array
from ..errors import DeviceTimeoutError, InputError, LimitError

__all__ = ["Camera", "Clock", "Manipulator", "RealClock"]


class Clock(abc.ABC):
    """Time source of a procedure: the wall clock, or a simulated one."""

    @abc.abstractmethod
    def now_s(self) -> float:
        """Seconds since an arbitrary origin (monotonic)."""

    @abc.abstractmethod
    def sleep(self, duration_s: float) -> None:
        """Wait ``duration_s`` seconds."""


class RealClock(Clock):
    """The machine's monotonic clock."""

    def now_s(self) -> float:
        return time.monotonic()

    def sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s)


class Manipulator(abc.ABC):
    """A Cartesian micromanipulator with one linear joint per axis, positions in µm.

    Subclasses implement :meth:`_move`, :meth:`position_um`, :meth:`is_moving` and
    :meth:`stop`; :meth:`move_to_um` checks the soft limits first, so no backend can be
    commanded outside them.
    """

    def __init__(self, name: str, axes: tuple[str, ...], limits_um: ArrayLike) -> None:
        self.name = name
        self.axes = tuple(axes)
        lim = as_array(limits_um, "limits_um", (len(self.axes), 2))
        if np.any(lim[:, 0] >= lim[:, 1]):
            raise InputError(f"limits_um: expected low < high for every axis, got {lim.tolist()}")
        self.limits_um: FloatArray = lim

    @property
    def n_axes(self) -> int:
        """Number of joints."""
        return len(self.axes)

    def check_limits(self, d_um: ArrayLike) -> FloatArray:
        """Validate a joint command: shape, finiteness and the soft limits."""
        d = as_array(d_um, "d_um", (self.n_axes,))
        lo, hi = self.limits_um[:, 0], self.limits_um[:, 1]
        outside = np.flatnonzero((d < lo) | (d > hi))
        if outside.size:
            k = int(outside[0])
            raise LimitError(
                f"{self.name}: axis {self.axes[k]} = {d[k]:.3f} µm is outside the soft limits "
                f"[{lo[k]:g}, {hi[k]:g}] µm; nothing was moved"
            )
        return d

    def move_to_um(self, d_um: ArrayLike) -> None:
        """Start an absolute move of every joint (returns at once; see :meth:`is_moving`).

        Raises
        ------
        LimitError
            Outside the soft limits (nothing is sent).
        DeviceError
            The controller refused or failed.
        """
        self._move(self.check_limits(d_um))

    def wait_until_stopped(
        self, clock: Clock, timeout_s: float = 30.0, poll_s: float = 0.02, retries: int = 5
    ) -> float:
        """Poll :meth:`is_moving` until false; returns the time waited.

        A status query that times out is asked again (up to ``retries`` times in a row).

        Raises
        ------
        DeviceTimeoutError
            Still moving after ``timeout_s``, or the device stopped answering.
        """
        start = clock.now_s()
        failures = 0
        while True:
            try:
                moving = self.is_moving()
                failures = 0
            except DeviceTimeoutError:
                failures += 1
                if failures > retries:
                    raise
                moving = True
            if not moving:
                return clock.now_s() - start
            if clock.now_s() - start > timeout_s:
                raise DeviceTimeoutError(f"{self.name}: still moving after {timeout_s:g} s")
            clock.sleep(poll_s)

    @abc.abstractmethod
    def _move(self, d_um: FloatArray) -> None:
        """Send the (checked) absolute move."""

    @abc.abstractmethod
    def position_um(self) -> FloatArray:
        """Joint positions reported by the device's own sensors, (n_axes,) µm."""

    @abc.abstractmethod
    def is_moving(self) -> bool:
        """True while the device's own position loop has not settled."""

    @abc.abstractmethod
    def stop(self) -> None:
        """Stop all motion now."""


class Camera(abc.ABC):
    """A camera that grabs single frames on request."""

    def __init__(
        self,
        name: str,
        sensor_size_px: tuple[int, int],
        pixel_size_um: float,
        bit_depth: int,
        exposure_s: float,
    ) -> None:
        self.name = name
        self.sensor_size_px = (int(sensor_size_px[0]), int(sensor_size_px[1]))
        self.pixel_size_um = float(pixel_size_um)
        if bit_depth not in (8, 10, 12, 14, 16):
            raise InputError(f"bit_depth: expected 8, 10, 12, 14 or 16, got {bit_depth}")
        self.bit_depth = bit_depth
        self._exposure_s = float(exposure_s)

    @property
    def exposure_s(self) -> float:
        """Exposure time, seconds."""
        return self._exposure_s

    @exposure_s.setter
    def exposure_s(self, value: float) -> None:
        if not value > 0:
            raise InputError(f"exposure_s: expected > 0, got {value}")
        self._apply_exposure(float(value))
        self._exposure_s = float(value)

    def _apply_exposure(self, exposure_s: float) -> None:  # noqa: B027 (an optional hook)
        """Send a new exposure to the device (drivers override; nothing by default)."""

    @property
    def dtype(self) -> type[np.unsignedinteger]:
        """uint8 for 8-bit cameras, uint16 above."""
        return np.uint8 if self.bit_depth == 8 else np.uint16

    @abc.abstractmethod
    def grab(self) -> NDArray[np.unsignedinteger]:
        """One frame, shape (height, width), dtype :attr:`dtype`.

        Raises
        ------
        FrameError, DeviceTimeoutError
            No frame (transient: grab again).
        """
