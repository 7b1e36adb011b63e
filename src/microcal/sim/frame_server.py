"""The digital twin's frame server: the platform's cameras (and stages) behind the frame
protocol.

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

A SNAP exposes a frame as GRAB does and keeps it (the last
:data:`~microcal.devices.twin_protocol.KEPT_FRAMES`), made only where a REGION reads it: a
camera of 2048 x 2048 pixels costs a region's pixels, not the whole frame's. The stage
requests (MOVE, POS, BUSY, STOP) reach the served stages (:class:`ServedStage`: the
``patch`` preset's focus drive and X-Y stage, :mod:`microcal.sim.patch_twin`); a platform's
twin has none.
"""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections import OrderedDict
from collections.abc import Callable, Mapping
from typing import Any, Protocol

import numpy as np

from ..devices.base import Clock
from ..devices.twin_protocol import (
    BUSY,
    EXPOSURE,
    GRAB,
    INFO,
    INFO_FORMAT,
    KEPT_FRAMES,
    KIND_BUSY,
    KIND_DEVICE,
    KIND_FRAME,
    KIND_INPUT,
    KIND_LIMIT,
    KIND_TIMEOUT,
    MOVE,
    POS,
    REGION,
    SNAP,
    STAGE_KINDS,
    STOP,
    TRUTH,
    CameraInfo,
    StageInfo,
    encode_error,
    encode_frame,
    encode_json,
    encode_ok,
)
from ..errors import DeviceTimeoutError, FrameError, LimitError, MicrocalError
from ..vision.lazy_frame import ArrayFrame, RegionFrame
from .line_server import RequestTimeoutError, held
from .platforms import SimPlatform
from .scaled_clock import DeferredWait, ScaledClock

__all__ = ["FramePeer", "ServedCamera", "ServedStage"]


class ServedCamera(Protocol):
    """What the frame server serves of a camera (a simulated camera's attributes)."""

    sensor_size_px: tuple[int, int]
    bit_depth: int
    pixel_size_um: float
    exposure_s: float

    @property
    def dtype(self) -> Any:
        """The frames' pixel type."""
        ...

    def grab(self) -> Any:
        """One whole frame, (height, width)."""
        ...


class ServedStage(Protocol):
    """A stage the frame server serves (MOVE, POS, BUSY, STOP), µm per axis."""

    info: StageInfo

    def move(self, values_um: tuple[float, ...]) -> None:
        """Move to ``values_um`` (one per axis); LimitError outside the travel."""
        ...

    def position(self) -> tuple[float, ...]:
        """The readout, one value per axis."""
        ...

    def busy(self) -> bool:
        """True while it moves."""
        ...

    def stop(self) -> None:
        """Stop where it is."""
        ...


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
        self.serve(plat.cameras, {}, plat.clock, lock, preset=preset, seed=seed,
                   time_scale=time_scale, stop=stop)  # fmt: skip

    def serve(
        self, cameras: Mapping[str, ServedCamera], stages: Mapping[str, ServedStage],
        clock: Clock, lock: threading.Lock, *, preset: str, seed: int, time_scale: float,
        stop: threading.Event | None = None,
    ) -> None:  # fmt: skip
        """Set what the server serves (a subclass serving other devices calls it)."""
        self.cameras, self.stages, self.clock = cameras, stages, clock
        self.lock = lock
        self.stop = stop if stop is not None else threading.Event()
        self.info: dict[str, Any] = {
            "format": INFO_FORMAT,
            "preset": preset,
            "seed": seed,
            "time_scale": time_scale,
        }
        self._kept: OrderedDict[int, RegionFrame] = OrderedDict()
        self._next_id = 1

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
        clock = self.clock
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
        if request == SNAP and len(args) == 1:
            return self._snap(args[0])
        if request == REGION and len(args) == 5:
            return self._region(args)
        if request in (MOVE, POS, BUSY, STOP) and args:
            return self._stage_request(request, args)
        asked = " ".join(words)[:60]
        expected = (
            f"{INFO}, {GRAB} <camera>, {SNAP} <camera>, {REGION} <id> <x0> <y0> <x1> <y1>, "
            f"{EXPOSURE} <camera> <ms>, {MOVE}|{POS}|{BUSY}|{STOP} <stage> ... or {TRUTH}"
        )
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
        """The INFO answer: the twin, its cameras and its stages."""
        cameras = [
            CameraInfo(
                name=name,
                width=cam.sensor_size_px[0],
                height=cam.sensor_size_px[1],
                bit_depth=cam.bit_depth,
                dtype=np.dtype(cam.dtype).name,
                pixel_size_um=cam.pixel_size_um,
                exposure_ms=cam.exposure_s * 1e3,
                regions=bool(getattr(cam, "regions", False)),
            ).to_json()
            for name, cam in self.cameras.items()
        ]
        stages = [stage.info.to_json() for stage in self.stages.values()]
        return {**self.info, "cameras": cameras, "stages": stages}

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

    def _camera(self, name: str) -> ServedCamera | None:
        return self.cameras.get(name)

    def _grab(self, name: str) -> bytes:
        cam = self._camera(name)
        if cam is None:
            return self._no_camera(name)
        return _device_call(lambda: encode_frame(cam.grab()))

    def _snap(self, name: str) -> bytes:
        cam = self._camera(name)
        if cam is None:
            return self._no_camera(name)
        lazy: Callable[[], RegionFrame] | None = getattr(cam, "grab_lazy", None)

        def snap() -> bytes:
            frame = lazy() if callable(lazy) else ArrayFrame(cam.grab())
            frame_id, self._next_id = self._next_id, self._next_id + 1
            self._kept[frame_id] = frame
            while len(self._kept) > KEPT_FRAMES:
                self._kept.popitem(last=False)
            h, w = frame.shape
            return f"OK {frame_id} {h} {w} {np.dtype(cam.dtype).name}".encode("ascii") + b"\r\n"

        return _device_call(snap)

    def _region(self, args: list[str]) -> bytes:
        try:
            frame_id, x0, y0, x1, y1 = (int(a) for a in args)
        except ValueError:
            return encode_error(
                KIND_INPUT, f"region: expected integers, got {' '.join(args)[:60]!r}"
            )
        frame = self._kept.get(frame_id)
        if frame is None:
            return encode_error(
                KIND_INPUT, f"region: frame {frame_id} is not kept (the server keeps the last "
                f"{KEPT_FRAMES} frames of {SNAP}); snap again",
            )  # fmt: skip
        h, w = frame.shape
        if not (0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h):
            return encode_error(
                KIND_INPUT, f"region: the box {x0} {y0} {x1} {y1} is not inside the frame of "
                f"{w} x {h} pixels (0 <= x0 < x1 <= width, 0 <= y0 < y1 <= height)",
            )  # fmt: skip
        return _device_call(lambda: encode_frame(frame.region(x0, y0, x1, y1)))

    def _stage_request(self, request: str, args: list[str]) -> bytes:
        stage = self.stages.get(args[0])
        if stage is None:
            names = ", ".join(self.stages) or "none"
            return encode_error(KIND_INPUT, f"no stage {args[0]!r} (stages: {names})")
        axes = STAGE_KINDS[stage.info.kind]
        if request != MOVE and len(args) != 1:
            return encode_error(KIND_INPUT, f"{request.lower()}: expected {request} <stage>")
        if request == POS:
            return _device_call(lambda: _ok_values(stage.position()))
        if request == BUSY:
            return _device_call(lambda: _ok_values((1.0 if stage.busy() else 0.0,)))
        if request == STOP:
            return _device_call(lambda: _done(stage.stop))
        values = [_finite(a) for a in args[1:]]
        if len(values) != axes or any(v is None for v in values):
            return encode_error(
                KIND_INPUT, f"move: stage {args[0]} takes {axes} finite number(s) of µm, got "
                f"{' '.join(args[1:])[:60]!r}",
            )  # fmt: skip
        target = tuple(float(v) for v in values if v is not None)
        return _device_call(lambda: _done(lambda: stage.move(target)))

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
        cameras = ", ".join(self.cameras)
        return encode_error(KIND_INPUT, f"no camera {name!r} (cameras: {cameras})")


def _device_call(what: Callable[[], bytes]) -> bytes:
    """``what()``'s answer, or the ERR line of the device error it raised: ``frame`` (a
    dropped frame), ``timeout``, ``limit`` (a position outside a stage's travel), ``device``."""
    try:
        return what()
    except FrameError as exc:
        return encode_error(KIND_FRAME, str(exc))
    except DeviceTimeoutError as exc:
        return encode_error(KIND_TIMEOUT, str(exc))
    except LimitError as exc:
        return encode_error(KIND_LIMIT, str(exc))
    except MicrocalError as exc:
        return encode_error(KIND_DEVICE, str(exc))


def _done(what: Callable[[], None]) -> bytes:
    """``OK`` once ``what()`` is done."""
    what()
    return encode_ok()


def _ok_values(values: tuple[float, ...]) -> bytes:
    """``OK <v> ...`` (each value as Python writes a float: exact)."""
    return ("OK " + " ".join(repr(float(v)) for v in values)).encode("ascii") + b"\r\n"


def _finite(text: str) -> float | None:
    try:
        value = float(text)
    except ValueError:
        return None
    return value if math.isfinite(value) else None
