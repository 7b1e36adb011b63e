"""Base classes of the devices microcal drives: manipulators, cameras, clocks.

Every backend (the simulator, the SmarAct driver, a Micro-Manager bridge) subclasses these,
so procedures work with any of them. The base classes hold the behaviour that must be the
same everywhere: a move outside the soft limits raises :class:`LimitError` before anything is
sent; joint values are in µm; frames are numpy arrays; a clock refuses a negative or
non-finite wait.

Devices have a lifecycle: they are open once constructed (a driver may need a ``connect()``
first) and :meth:`Device.close` releases them for good. ``close()`` is idempotent and may be
left to a ``with`` block; afterwards every operation raises :class:`DeviceError`. The public
operations are template methods: the base class checks the state (and the limits) and calls
the backend's protected hook (``_move``, ``_position_um``, ``_grab``, ``_close``, ...).
"""

from __future__ import annotations

import abc
import math
import time
from types import TracebackType
from typing import Self

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .._validation import FloatArray, as_array, check_limits
from ..errors import DeviceError, DeviceTimeoutError, InputError

__all__ = ["Camera", "Clock", "Device", "Manipulator", "RealClock"]


class Clock(abc.ABC):
    """Time source of a procedure: the wall clock, or a simulated one.

    :meth:`sleep` validates the duration the same way for every clock and then calls the
    subclass's :meth:`_sleep`.
    """

    @abc.abstractmethod
    def now_s(self) -> float:
        """Seconds since an arbitrary origin (monotonic)."""

    def sleep(self, duration_s: float) -> None:
        """Wait ``duration_s`` seconds (0 returns at once).

        Raises
        ------
        InputError
            A negative, NaN or infinite duration (callers clamp computed waits with
            ``max(0.0, x)``).
        """
        try:
            d = float(duration_s)
        except (TypeError, ValueError):
            d = math.nan
        if not (math.isfinite(d) and d >= 0):
            raise InputError(f"sleep: expected a finite duration >= 0 s, got {duration_s!r}")
        self._sleep(d)

    @abc.abstractmethod
    def _sleep(self, duration_s: float) -> None:
        """Wait a (checked: finite, >= 0) duration."""


class RealClock(Clock):
    """The machine's monotonic clock."""

    def now_s(self) -> float:
        return time.monotonic()

    def _sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s)


class Device(abc.ABC):
    """What every device has: a name and a lifecycle (open until :meth:`close`).

    Subclasses implement :meth:`_close` (release the connection, stream or handles) and call
    :meth:`_check_open` at the start of every public operation; :class:`Manipulator` and
    :class:`Camera` already do so for theirs.
    """

    #: What the device is, in messages ("manipulator", "camera").
    kind = "device"

    def __init__(self, name: str) -> None:
        self.name = name
        self._closed = False

    @property
    def closed(self) -> bool:
        """True once :meth:`close` has been called."""
        return self._closed

    def close(self) -> None:
        """Release the device; it cannot be used afterwards. Calling it again does nothing.

        The backend's :meth:`_close` runs exactly once; if it raises, the device counts as
        closed all the same (its error is passed on).
        """
        if self._closed:
            return
        self._closed = True
        self._close()

    @abc.abstractmethod
    def _close(self) -> None:
        """Release what the device holds (called once, by :meth:`close`)."""

    def _check_open(self, operation: str) -> None:
        """Raise :class:`DeviceError` if the device is closed."""
        if self._closed:
            raise DeviceError(
                f"{self.name}: {operation} on a closed {self.kind}; open the device again to use it"
            )

    def __enter__(self) -> Self:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()


class Manipulator(Device):
    """A Cartesian micromanipulator with one linear joint per axis, positions in µm.

    An axis whose soft limits are one value (low == high) is **held**: the device cannot move
    it (a two-axis X-Y positioner presented with the three joints x, y, z, see
    :class:`~microcal.devices.held_axes.HeldAxes`), and every command must give it that value.

    Subclasses implement :meth:`_move`, :meth:`_position_um`, :meth:`_is_moving`,
    :meth:`_stop` and :meth:`_close`. The public methods check first that the device is open
    (and :meth:`move_to_um` that the command is within the soft limits), so no backend can be
    commanded outside them or after :meth:`close`.
    """

    kind = "manipulator"

    def __init__(self, name: str, axes: tuple[str, ...], limits_um: ArrayLike) -> None:
        super().__init__(name)
        self.axes = tuple(axes)
        lim = as_array(limits_um, "limits_um", (len(self.axes), 2))
        if np.any(lim[:, 0] > lim[:, 1]) or np.all(lim[:, 0] == lim[:, 1]):
            raise InputError(
                f"limits_um: expected low < high for every axis (low == high for an axis the "
                f"device holds still), got {lim.tolist()}"
            )
        self.limits_um: FloatArray = lim

    @property
    def n_axes(self) -> int:
        """Number of joints."""
        return len(self.axes)

    @property
    def identity(self) -> str:
        """Which device this is, as it says itself (a controller's serial number and the
        channels; empty when the backend cannot tell). A calibration records it, and a
        calibration of another device is refused."""
        return ""

    def check_limits(self, d_um: ArrayLike) -> FloatArray:
        """Validate a joint command, (n_axes,) µm: shape, finiteness and the soft limits."""
        d = as_array(d_um, "d_um", (self.n_axes,))
        return check_limits(d, self.limits_um, axes=self.axes, owner=self.name)

    @property
    def held(self) -> np.ndarray:
        """(n_axes,) bool: the axes the device holds still (soft limits of one value)."""
        held: np.ndarray = self.limits_um[:, 0] == self.limits_um[:, 1]
        return held

    def below_um(self, d_um: ArrayLike, distance_um: float) -> FloatArray:
        """Where an approach from below to ``d_um`` starts: ``distance_um`` under it on every
        joint, except a held one (it keeps its value), (n_axes,) µm; not checked."""
        d = np.asarray(d_um, dtype=np.float64)
        out: FloatArray = np.where(self.held, d, d - distance_um)
        return out

    def move_to_um(self, d_um: ArrayLike) -> None:
        """Start an absolute move of every joint, (n_axes,) µm (returns at once).

        See :meth:`is_moving` for when it has arrived.

        Raises
        ------
        LimitError
            Outside the soft limits (nothing is sent).
        DeviceError
            The controller refused or failed, or the device is closed.
        """
        self._check_open("move")
        self._move(self.check_limits(d_um))

    def position_um(self) -> FloatArray:
        """Joint positions reported by the device's own sensors, (n_axes,) µm."""
        self._check_open("position query")
        return self._position_um()

    def is_moving(self) -> bool:
        """True while the device's own position loop has not settled."""
        self._check_open("status query")
        return self._is_moving()

    def stop(self) -> None:
        """Stop all motion now."""
        self._check_open("stop")
        self._stop()

    def wait_until_stopped(
        self, clock: Clock, timeout_s: float = 30.0, poll_s: float = 0.02, retries: int = 5
    ) -> float:
        """Poll :meth:`is_moving` until false; returns the time waited, s.

        A status query that times out is asked again (up to ``retries`` times in a row).

        Raises
        ------
        DeviceTimeoutError
            Still moving after ``timeout_s``, or the device stopped answering.
        DeviceError
            The device is closed.
        """
        self._check_open("wait")
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
        """Send the (checked) absolute move, (n_axes,) µm."""

    @abc.abstractmethod
    def _position_um(self) -> FloatArray:
        """Read the joint positions, (n_axes,) µm."""

    @abc.abstractmethod
    def _is_moving(self) -> bool:
        """Read whether the device's position loop is still moving."""

    @abc.abstractmethod
    def _stop(self) -> None:
        """Stop all motion."""


class Camera(Device):
    """A camera that grabs single frames on request.

    Subclasses implement :meth:`_grab` and :meth:`_close`, and :meth:`_apply_exposure` if
    the exposure is a device setting.
    """

    kind = "camera"

    def __init__(
        self,
        name: str,
        sensor_size_px: tuple[int, int],
        pixel_size_um: float,
        bit_depth: int,
        exposure_s: float,
    ) -> None:
        super().__init__(name)
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
        self._check_open("exposure change")
        if not value > 0:
            raise InputError(f"exposure_s: expected > 0, got {value}")
        self._apply_exposure(float(value))
        self._exposure_s = float(value)

    def _apply_exposure(self, exposure_s: float) -> None:
        """Send a new exposure to the device (drivers override; nothing by default)."""

    @property
    def dtype(self) -> type[np.unsignedinteger]:
        """uint8 for 8-bit cameras, uint16 above."""
        return np.uint8 if self.bit_depth == 8 else np.uint16

    def grab(self) -> NDArray[np.unsignedinteger]:
        """One frame, shape (height, width), dtype :attr:`dtype`; the caller's own array.

        Raises
        ------
        FrameError, DeviceTimeoutError
            No frame (transient: grab again).
        DeviceError
            The camera failed or is closed.
        """
        self._check_open("grab")
        return self._grab()

    @abc.abstractmethod
    def _grab(self) -> NDArray[np.unsignedinteger]:
        """Grab one frame, shape (height, width), dtype :attr:`dtype`."""
