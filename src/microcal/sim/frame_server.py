"""The digital twin's frame server: the platform's cameras behind the frame protocol.

:mod:`microcal.sim.twin` serves it on ``frames_port``; the protocol, its words and its
limits are :mod:`microcal.devices.twin_protocol`'s (its docstring has the table), read on the
other side by the twin's cameras (:mod:`microcal.devices.twin_camera`).

What the cameras see follows the simulator's scene (:mod:`microcal.sim.stage`): the
calibration target on the target stage while the stage was moved more recently than the
manipulator, the end-effector's board otherwise.

A GRAB holds the platform's lock only while the frame is rendered: its exposure and readout
are then waited out without it (:meth:`~microcal.sim.scaled_clock.ScaledClock.deferred_waits`),
so a long exposure holds up neither the MCS2 peer nor the other cameras, and the frames are
those the camera renders when its lock is held throughout. The wait ends at the request's
deadline (the answer is then ``ERR timeout ...``) or when the twin closes. The server's
bounds (clients, idle time, request time, line length) are :mod:`microcal.sim.line_server`'s;
beyond its clients a connection is told ``ERR busy ...``.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from typing import Any

import numpy as np

from ..devices.twin_protocol import (
    EXPOSURE,
    GRAB,
    INFO,
    INFO_FORMAT,
    KIND_BUSY,
    KIND_DEVICE,
    KIND_FRAME,
    KIND_INPUT,
    KIND_TIMEOUT,
    TRUTH,
    CameraInfo,
    encode_error,
    encode_frame,
    encode_json,
    encode_ok,
)
from ..errors import DeviceTimeoutError, FrameError, MicrocalError
from .camera import SimCamera
from .line_server import RequestTimeoutError, held
from .platforms import SimPlatform
from .scaled_clock import DeferredWait, ScaledClock

__all__ = ["FramePeer"]


class FramePeer:
    """The frame server's requests over the platform's cameras.

    Parameters
    ----------
    plat : SimPlatform
    lock : threading.Lock
        Held for every access to the platform (not while an exposure is waited out, when the
        platform's clock is a :class:`ScaledClock`).
    preset, seed, time_scale :
        The twin's, told in the INFO answer.
    stop : threading.Event, optional
        The twin's: set, it ends an exposure's wait.
    """

    def __init__(
        self, plat: SimPlatform, lock: threading.Lock, *, preset: str, seed: int,
        time_scale: float, stop: threading.Event | None = None,
    ) -> None:  # fmt: skip
        self.plat = plat
        self.lock = lock
        self.stop = stop if stop is not None else threading.Event()
        self.info: dict[str, Any] = {
            "format": INFO_FORMAT,
            "preset": preset,
            "seed": seed,
            "time_scale": time_scale,
        }

    def handle(self, line: bytes, deadline: float = math.inf) -> bytes | None:
        """The answer to one request line (None for an empty line).

        Raises
        ------
        RequestTimeoutError
            ``deadline`` (``time.monotonic()``) passed waiting for the lock or an exposure.
        """
        words = line.decode("ascii", errors="replace").split()
        if not words:
            return None
        with held(self.lock, deadline), self._deferred_waits() as owed:
            answer = self._answer(words)
        if owed.wall_s > 0:  # the exposure and readout, the lock released
            left = deadline - time.monotonic()
            self.stop.wait(min(owed.wall_s, max(0.0, left)))
            if owed.wall_s > left:
                raise RequestTimeoutError
        return answer

    def _deferred_waits(self) -> contextlib.AbstractContextManager[DeferredWait]:
        clock = self.plat.clock
        if isinstance(clock, ScaledClock):
            return clock.deferred_waits()
        return contextlib.nullcontext(DeferredWait())  # waits under the lock, as they come

    def _answer(self, words: list[str]) -> bytes:
        request, args = words[0].upper(), words[1:]
        if request == INFO and not args:
            return encode_json(self.describe())
        if request == TRUTH and not args:
            return encode_json(self.truth())
        if request == GRAB and len(args) == 1:
            return self._grab(args[0])
        if request == EXPOSURE and len(args) == 2:
            return self._exposure(*args)
        asked = " ".join(words)[:60]
        expected = f"{INFO}, {GRAB} <camera>, {EXPOSURE} <camera> <ms> or {TRUTH}"
        return encode_error(KIND_INPUT, f"unknown request {asked!r}; expected {expected}")

    def busy_answer(self, max_clients: int) -> bytes:
        """``ERR busy ...``: the line a connection beyond ``max_clients`` gets."""
        return encode_error(
            KIND_BUSY,
            f"the frame server serves {max_clients} clients at once (max_clients); try "
            "again when one has closed",
        )

    def timeout_answer(self, line: bytes, timeout_s: float) -> bytes:
        """``ERR timeout ...``: the answer to a request longer than the request timeout."""
        asked = line.decode("ascii", errors="replace")[:60]
        return encode_error(
            KIND_TIMEOUT, f"no answer to {asked!r} within the request timeout of {timeout_s:g} s"
        )

    def describe(self) -> dict[str, Any]:
        """The INFO answer: the twin and its cameras."""
        cameras = [
            CameraInfo(
                name=name,
                width=cam.sensor_size_px[0],
                height=cam.sensor_size_px[1],
                bit_depth=cam.bit_depth,
                dtype=np.dtype(cam.dtype).name,
                pixel_size_um=cam.pixel_size_um,
                exposure_ms=cam.exposure_s * 1e3,
            ).to_json()
            for name, cam in self.plat.cameras.items()
        ]
        return {**self.info, "cameras": cameras}

    def truth(self) -> dict[str, Any]:
        """The TRUTH answer: the true end-effector position and stage joints now, µm."""
        t = self.plat.clock.now_s()
        stage = self.plat.target_stage
        return {
            "t_s": t,
            "position_um": self.plat.manipulator.true_position_um(t).tolist(),
            "target_stage_um": None if stage is None else stage.joints_um(t).tolist(),
            "devices": {
                n: m.true_position_um(t).tolist() for n, m in self.plat.manipulators.items()
            },
        }

    def _camera(self, name: str) -> SimCamera | None:
        return self.plat.cameras.get(name)

    def _grab(self, name: str) -> bytes:
        cam = self._camera(name)
        if cam is None:
            return self._no_camera(name)
        try:
            frame = cam.grab()
        except FrameError as exc:
            return encode_error(KIND_FRAME, str(exc))
        except DeviceTimeoutError as exc:
            return encode_error(KIND_TIMEOUT, str(exc))
        except MicrocalError as exc:
            return encode_error(KIND_DEVICE, str(exc))
        return encode_frame(frame)

    def _exposure(self, name: str, ms: str) -> bytes:
        cam = self._camera(name)
        if cam is None:
            return self._no_camera(name)
        try:
            value = float(ms)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and 0 < value <= 60_000):
            return encode_error(KIND_INPUT, f"exposure: expected 0 < ms <= 60000, got {ms!r}")
        cam.exposure_s = value / 1e3
        return encode_ok()

    def _no_camera(self, name: str) -> bytes:
        cameras = ", ".join(self.plat.cameras)
        return encode_error(KIND_INPUT, f"no camera {name!r} (cameras: {cameras})")
