"""The digital twin: the simulated platform served through the real devices' protocols.

One process holds a simulated platform (:func:`microcal.sim.platform`) on a clock that
follows the wall clock (:class:`ScaledClock`), and serves it on loopback, so that microcal's
hardware drivers drive it exactly as they drive a rig: the SmarAct MCS2 driver talks to the
manipulator and the target stage, and the Micro-Manager bridge grabs the cameras' frames
through pure-Python devices (:mod:`microcal.devices.twin_camera`). Moves take their time,
the end-effector creeps and drifts, and a frame takes its exposure and readout, all
``time_scale`` times faster than in real time.

Start it with ``microcal twin`` (or :class:`Twin` from Python) and open the rig file it
writes (:func:`twin_rig_toml`; ``examples/rigs/twin.toml`` for the default ports).

The MCS2 peer (``mcs2_port``, 55551 by default)
-----------------------------------------------
The controller's ASCII interface as :mod:`microcal.devices.smaract_mcs2` uses it: lines end
in ``\\r\\n``, commands may be chained with ``;`` on one line (their answers come back on one
line, joined by ``;``), positions and speeds are in picometres. Channels 0, 1, 2 are the
manipulator's x, y, z; channels 3, 4, 5 the target stage's; on the ``thesis-platform``
preset, 6, 7, 8 the second manipulator's (``m2``) and 9, 10 the X-Y positioner's (``p1``;
channel 11 is its held z, which its rig file leaves out).

==========================  ===============================================================
``:DEV:SNUM?``              ``"MCS2-TWIN-<seed>"``
``:SYST:ERR:NEXT?``         the oldest queued error ``code,"message"`` (``0,"No error"``)
``:SYST:ERR:COUN?``         the number of queued errors
``:MOVEn p``                move channel n to p pm: the device's other joints keep their last
                            commanded targets (the device's position at start)
``:STOPn``                  stop channel n's device (every joint of it) where it is
``:CHANn:POS?``             the device's position readout (sensor noise included), pm
``:CHANn:STAT?``            0x2 (closed loop), plus 0x1 while the device is moving
``:CHANn:MMOD m``, ``?``    the move mode (kept, 0 to 6)
``:CHANn:VEL v``, ``?``     the speed of channel n's device, pm/s (the sim moves every joint
                            of a device at one speed: the last setting wins)
==========================  ===============================================================

Refused commands queue an error, as the controller does: -113 an unknown command, -104 a
value that is not a number, -221 a channel that does not exist, -222 a move outside the
simulated device's limits (the driver refuses those before sending), -1015 a move the
simulated device refuses (a fault), -300 any other device error. A simulated timeout (a
fault) is silence: that line gets no answer.

The frame server (``frames_port``, 55561 by default)
----------------------------------------------------
A line protocol (ASCII, lines end in ``\\r\\n``; ``\\n`` is accepted), one request at a time
per connection:

==========================  ===============================================================
``INFO``                    one JSON line: ``{"format": "microcal.twin/1", "preset",
                            "seed", "time_scale", "cameras": [{"name", "width",
                            "height", "bit_depth", "dtype", "pixel_size_um",
                            "exposure_ms"}, ...]}``
``GRAB <camera>``           ``OK <height> <width> <dtype> <nbytes>`` then ``nbytes`` bytes:
                            the frame in row-major order, ``uint8`` or little-endian
                            ``uint16``; or ``ERR <kind> <message>`` when there is no frame
``EXPOSURE <camera> <ms>``  ``OK``, or ``ERR input <message>``
``TRUTH``                   one JSON line ``{"t_s", "position_um", "target_stage_um",
                            "devices"}``: the end-effector's true position, the stage's
                            true joints and every device's true position by name, µm
                            (ground truth: for tests and comparisons, never a calibration)
==========================  ===============================================================

``<kind>`` is ``frame`` (a dropped frame, grab again), ``timeout`` (no frame in time, grab
again), ``device`` (any other device error) or ``input`` (a request it does not take).

What the cameras see follows the simulator's scene (:mod:`microcal.sim.stage`): the
calibration target on the target stage while the stage was moved more recently than the
manipulator, the end-effector's board otherwise.

Every access to the platform holds one lock; each connection has its own thread. Every
loop is bounded: the servers end with :meth:`Twin.close` or after ``max_lifetime_s``.
"""

from __future__ import annotations

import contextlib
import ipaddress
import json
import math
import signal
import socket
import threading
import time
from collections import deque
from collections.abc import Callable, Mapping
from types import TracebackType
from typing import Any, Self

import numpy as np

from .._validation import FloatArray
from ..devices.base import Clock
from ..errors import (
    DeviceError,
    DeviceTimeoutError,
    FrameError,
    InputError,
    LimitError,
    MicrocalError,
    MoveError,
)
from ..json_value import JsonValue
from .camera import SimCamera
from .manipulator import SimManipulator
from .platforms import SimPlatform, platform
from .stage import SimStage

__all__ = [
    "FRAMES_PORT",
    "MCS2_PORT",
    "RIG_HEADER",
    "ScaledClock",
    "Twin",
    "twin_rig_toml",
]

#: The MCS2 controller's standard port.
MCS2_PORT = 55551
#: The frame server's default port.
FRAMES_PORT = 55561
#: The first line of every rig file :func:`twin_rig_toml` writes (how microcal knows its own).
RIG_HEADER = "# The digital twin's rig, written by microcal twin."
#: The frame server's INFO format.
INFO_FORMAT = "microcal.twin/1"
PM_PER_UM = 1_000_000
#: How long the servers live at most, s (every loop is bounded in time).
MAX_LIFETIME_S = 7 * 24 * 3600.0
_MAX_LINE_BYTES = 4096
_MAX_COMMANDS_PER_LINE = 32
_POLL_S = 0.2  # the servers' socket timeout: how soon they notice close()
_SEND_TIMEOUT_S = 30.0  # longest time to hand one answer (a frame) to a client
MOVING, CLOSED_LOOP = 0x1, 0x2
# the controller's error codes (SCPI's where it has one)
ERR_DATA_TYPE = -104
ERR_UNDEFINED_HEADER = -113
ERR_SETTINGS_CONFLICT = -221
ERR_OUT_OF_RANGE = -222
ERR_DEVICE = -300
ERR_MOVEMENT_FAILED = -1015


class ScaledClock(Clock):
    """Simulated seconds that follow the wall clock, ``time_scale`` times faster.

    ``now_s() = (time.monotonic() - t0) * time_scale`` with ``t0`` the moment of
    construction; ``sleep(d)`` waits ``d / time_scale`` wall seconds.

    Parameters
    ----------
    time_scale : float
        Simulated seconds per wall second (> 0; 1 is real time).

    Raises
    ------
    InputError
        A time scale that is not a finite number > 0.
    """

    def __init__(self, time_scale: float = 1.0) -> None:
        self.time_scale = _time_scale(time_scale)
        self._t0 = time.monotonic()

    def now_s(self) -> float:
        return (time.monotonic() - self._t0) * self.time_scale

    def _sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s / self.time_scale)


def _time_scale(value: object) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]  # anything else is refused below
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, bool) or not (math.isfinite(v) and v > 0):
        raise InputError(f"time_scale: expected a finite number > 0, got {value!r}")
    return v


def _ascii(text: str) -> str:
    """A message fit for one protocol line: ASCII, no quotes, separators or line ends."""
    clean = text.replace("µ", "u").replace('"', "'").replace(";", ",")
    clean = " ".join(clean.split())
    return clean.encode("ascii", errors="replace").decode("ascii")


class _NoAnswerError(Exception):
    """The line gets no answer (a simulated timeout)."""


SimDevice = SimManipulator | SimStage


class _MCS2Peer:
    """The controller's command set over the platform's manipulator and target stage."""

    def __init__(self, plat: SimPlatform, lock: threading.Lock, serial: str) -> None:
        self.lock = lock
        self.serial = serial
        self.devices: list[SimDevice] = [plat.manipulator]
        if plat.target_stage is not None:
            self.devices.append(plat.target_stage)
        self.devices += [m for name, m in plat.manipulators.items() if name != "m1"]
        now = plat.clock.now_s()
        #: Per device, the joint targets last commanded, (3,) µm.
        self.targets = [d.joints_um(now).copy() for d in self.devices]
        self.modes = [0] * (3 * len(self.devices))
        self.errors: deque[tuple[int, str]] = deque(maxlen=64)
        self.log: deque[str] = deque(maxlen=1000)  # the last commands received (for tests)
        self.clock = plat.clock

    def handle(self, line: bytes) -> bytes | None:
        """The answer line to one line of ``;``-chained commands (None: no answer)."""
        text = line.decode("ascii", errors="replace")
        answers = []
        with self.lock:
            try:
                for part in text.split(";")[:_MAX_COMMANDS_PER_LINE]:
                    command = part.strip()
                    if command:
                        self.log.append(command)
                        out = self._one(command)
                        if out is not None:
                            answers.append(out)
            except _NoAnswerError:
                return None
        return (";".join(answers) + "\r\n").encode("ascii") if answers else None

    def _channel(self, text: str) -> tuple[SimDevice, int, int] | None:
        """(device, joint, device index) of a channel number, or None (error queued)."""
        try:
            n = int(text)
        except ValueError:
            n = -1
        if not 0 <= n < 3 * len(self.devices):
            self.errors.append((ERR_SETTINGS_CONFLICT, f"Settings conflict: no channel {text}"))
            return None
        return self.devices[n // 3], n % 3, n // 3

    def _number(self, text: str) -> float | None:
        try:
            v = float(text)
        except ValueError:
            v = math.nan
        if not math.isfinite(v):
            self.errors.append((ERR_DATA_TYPE, f"Data type error: {text.strip()!r}"))
            return None
        return v

    def _guarded(self, what: Callable[[], Any]) -> tuple[bool, Any]:
        """Run a device operation: (True, its value), or (False, None) with its error queued.

        A simulated timeout is silence: the line gets no answer.
        """
        try:
            return True, what()
        except DeviceTimeoutError:
            raise _NoAnswerError from None
        except LimitError as exc:
            self.errors.append((ERR_OUT_OF_RANGE, _ascii(f"Data out of range: {exc}")))
        except MoveError as exc:
            self.errors.append((ERR_MOVEMENT_FAILED, _ascii(f"Movement failed: {exc}")))
        except MicrocalError as exc:
            self.errors.append((ERR_DEVICE, _ascii(f"Device-specific error: {exc}")))
        return False, None

    def _one(self, command: str) -> str | None:
        upper = command.upper()
        if upper == ":DEV:SNUM?":
            return f'"{self.serial}"'
        if upper == ":SYST:ERR:NEXT?":
            code, message = self.errors.popleft() if self.errors else (0, "No error")
            return f'{code},"{message}"'
        if upper == ":SYST:ERR:COUN?":
            return str(len(self.errors))
        if upper.startswith(":MOVE"):
            head, _, value = command[5:].partition(" ")
            self._move(head, value)
            return None
        if upper.startswith(":STOP"):
            found = self._channel(command[5:])
            if found is not None:
                device, _, k = found
                if self._guarded(device.stop)[0]:
                    self.targets[k] = device.joints_um(self.clock.now_s()).copy()
            return None
        if upper.startswith(":CHAN"):
            head, _, rest = command[5:].partition(":")
            key, _, value = rest.partition(" ")
            found = self._channel(head)
            return None if found is None else self._chan(found, key.upper(), value)
        self.errors.append((ERR_UNDEFINED_HEADER, f"Undefined header: {_ascii(command)[:40]}"))
        return None

    def _move(self, head: str, value: str) -> None:
        found = self._channel(head)
        pm = self._number(value) if found is not None else None
        if found is None or pm is None:
            return
        device, joint, k = found
        target = self.targets[k].copy()
        target[joint] = pm / PM_PER_UM
        if self._guarded(lambda: device.move_to_um(target))[0]:
            self.targets[k] = target

    def _chan(self, found: tuple[SimDevice, int, int], key: str, value: str) -> str | None:
        device, joint, k = found
        channel = 3 * k + joint
        if key == "POS?":
            position = self._guarded(device.position_um)[1]
            return "0" if position is None else str(round(float(position[joint]) * PM_PER_UM))
        if key == "STAT?":
            moving = self._guarded(device.is_moving)[1]
            return str(CLOSED_LOOP | (MOVING if moving else 0))
        if key == "MMOD?":
            return str(self.modes[channel])
        if key == "VEL?":
            return str(round(device.speed_um_s * PM_PER_UM))
        if key not in ("MMOD", "VEL"):
            self.errors.append((ERR_UNDEFINED_HEADER, f"Undefined header: :CHAN{channel}:{key}"))
            return None
        v = self._number(value)
        if v is None:
            return None
        if key == "MMOD" and v in range(7):
            self.modes[channel] = int(v)
        elif key == "VEL" and v > 0:
            device.speed_um_s = v / PM_PER_UM
        else:
            self.errors.append((ERR_OUT_OF_RANGE, f"Data out of range: {key} {value.strip()}"))
        return None


class _FramePeer:
    """The frame server's requests over the platform's cameras."""

    def __init__(self, plat: SimPlatform, lock: threading.Lock, info: Mapping[str, Any]) -> None:
        self.plat = plat
        self.lock = lock
        self.info = dict(info)

    def handle(self, line: bytes) -> bytes | None:
        words = line.decode("ascii", errors="replace").split()
        if not words:
            return None
        request, args = words[0].upper(), words[1:]
        with self.lock:
            if request == "INFO" and not args:
                return self._json(self.describe())
            if request == "TRUTH" and not args:
                return self._json(self.truth())
            if request == "GRAB" and len(args) == 1:
                return self._grab(args[0])
            if request == "EXPOSURE" and len(args) == 2:
                return self._exposure(*args)
        return _err("input", f"unknown request {' '.join(words)[:60]!r}; expected INFO, "
                    "GRAB <camera>, EXPOSURE <camera> <ms> or TRUTH")  # fmt: skip

    @staticmethod
    def _json(value: object) -> bytes:
        return json.dumps(value).encode("ascii") + b"\r\n"

    def describe(self) -> dict[str, JsonValue]:
        """The INFO answer: the twin and its cameras."""
        cameras: list[JsonValue] = [
            {
                "name": name,
                "width": cam.sensor_size_px[0],
                "height": cam.sensor_size_px[1],
                "bit_depth": cam.bit_depth,
                "dtype": np.dtype(cam.dtype).name,
                "pixel_size_um": cam.pixel_size_um,
                "exposure_ms": cam.exposure_s * 1e3,
            }
            for name, cam in self.plat.cameras.items()
        ]
        return {**self.info, "cameras": cameras}

    def truth(self) -> dict[str, JsonValue]:
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
            return _err("input", f"no camera {name!r} (cameras: {', '.join(self.plat.cameras)})")
        try:
            frame = cam.grab()
        except FrameError as exc:
            return _err("frame", str(exc))
        except DeviceTimeoutError as exc:
            return _err("timeout", str(exc))
        except MicrocalError as exc:
            return _err("device", str(exc))
        data = np.ascontiguousarray(frame, dtype=np.dtype(frame.dtype).newbyteorder("<"))
        h, w = data.shape
        header = f"OK {h} {w} {np.dtype(frame.dtype).name} {data.nbytes}\r\n"
        return header.encode("ascii") + data.tobytes()

    def _exposure(self, name: str, ms: str) -> bytes:
        cam = self._camera(name)
        if cam is None:
            return _err("input", f"no camera {name!r} (cameras: {', '.join(self.plat.cameras)})")
        try:
            value = float(ms)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and 0 < value <= 60_000):
            return _err("input", f"exposure: expected 0 < ms <= 60000, got {ms!r}")
        cam.exposure_s = value / 1e3
        return b"OK\r\n"


def _err(kind: str, message: str) -> bytes:
    return f"ERR {kind} {_ascii(message)}\r\n".encode("ascii")


class _LineServer:
    """A TCP server on one address: a thread per connection, each answering its lines."""

    def __init__(
        self,
        what: str,
        host: str,
        port: int,
        handle: Callable[[bytes], bytes | None],
        stop: threading.Event,
        deadline: float,
        max_connections: int,
    ) -> None:
        self.what, self.host, self.port = what, host, port
        self.handle = handle
        self.stop = stop
        self.deadline = deadline
        self.max_connections = max_connections
        self._server: socket.socket | None = None
        self._clients: set[socket.socket] = set()
        self._threads: list[threading.Thread] = []
        self._guard = threading.Lock()

    def running(self) -> bool:
        return not self.stop.is_set() and time.monotonic() < self.deadline

    def start(self) -> None:
        family = socket.AF_INET6 if ":" in self.host else socket.AF_INET
        server = socket.socket(family, socket.SOCK_STREAM)
        try:
            server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            server.bind((self.host, self.port))
            server.listen(self.max_connections)
        except OSError as exc:
            server.close()
            raise DeviceError(
                f"twin: the {self.what} cannot listen on {self.host}:{self.port} "
                f"({exc.strerror or exc}); is another twin running? choose another port"
            ) from None
        server.settimeout(_POLL_S)
        self.port = int(server.getsockname()[1])
        self._server = server
        self._spawn(self._accept_loop, server)

    def _spawn(self, target: Callable[..., None], *args: Any) -> None:
        thread = threading.Thread(target=target, args=args, daemon=True,
                                  name=f"twin-{self.what}")  # fmt: skip
        thread.start()
        self._threads.append(thread)

    def _accept_loop(self, server: socket.socket) -> None:
        while self.running():
            try:
                conn, _ = server.accept()
            except (TimeoutError, OSError):
                continue
            with self._guard:
                self._threads = [t for t in self._threads if t.is_alive()]
                if len(self._clients) >= self.max_connections:
                    conn.close()  # refused: too many at once
                    continue
                self._clients.add(conn)
            conn.settimeout(_POLL_S)
            self._spawn(self._serve, conn)

    def _serve(self, conn: socket.socket) -> None:
        buffer = b""
        try:
            while self.running():
                try:
                    chunk = conn.recv(65536)
                except TimeoutError:
                    continue
                if not chunk:
                    return
                buffer += chunk
                while b"\n" in buffer:
                    line, _, buffer = buffer.partition(b"\n")
                    answer = self.handle(line.rstrip(b"\r"))
                    if answer is not None:
                        conn.settimeout(_SEND_TIMEOUT_S)  # a frame: the whole of it
                        conn.sendall(answer)
                        conn.settimeout(_POLL_S)
                if len(buffer) > _MAX_LINE_BYTES:
                    return  # not a line of this protocol: drop the connection
        except OSError:
            return
        finally:
            with self._guard:
                self._clients.discard(conn)
            conn.close()

    def close(self) -> None:
        if self._server is not None:
            self._server.close()
        with self._guard:
            clients = list(self._clients)
        for conn in clients:
            with contextlib.suppress(OSError):
                conn.shutdown(socket.SHUT_RDWR)
        for thread in list(self._threads):
            if thread is not threading.current_thread():
                thread.join(timeout=2.0)


def _check_host(host: str) -> str:
    if host == "localhost":
        return "127.0.0.1"
    try:
        loopback = ipaddress.ip_address(host).is_loopback
    except ValueError:
        loopback = False
    if not loopback:
        raise InputError(f"host: the twin serves on loopback only (127.0.0.1, ::1), got {host!r}")
    return host


class Twin:
    """The simulated platform served through the MCS2 protocol and a frame server.

    ``with Twin(seed=0) as twin:`` starts both servers and closes them on leaving; the ports
    actually used are :attr:`mcs2_port` and :attr:`frames_port` once started.

    Parameters
    ----------
    preset, seed, overrides :
        The simulated platform (:func:`microcal.sim.platform`).
    host : str
        A loopback address to listen on.
    mcs2_port, frames_port : int
        TCP ports of the MCS2 peer and the frame server (0: any free port).
    time_scale : float
        Simulated seconds per wall second (:class:`ScaledClock`).
    max_connections : int
        Connections each server holds at once; more are closed at once.
    max_lifetime_s : float
        The servers stop by themselves after this long, s.

    Attributes
    ----------
    platform : SimPlatform
        The simulated platform (its ``truth_*`` for tests).
    serial : str
        The MCS2 peer's serial number, ``MCS2-TWIN-<seed>``.
    """

    def __init__(
        self,
        preset: str = "thesis",
        seed: int = 0,
        overrides: Mapping[str, Any] | None = None,
        *,
        host: str = "127.0.0.1",
        mcs2_port: int = MCS2_PORT,
        frames_port: int = FRAMES_PORT,
        time_scale: float = 1.0,
        max_connections: int = 8,
        max_lifetime_s: float = MAX_LIFETIME_S,
    ) -> None:
        self.host = _check_host(host)
        self.preset, self.seed = preset, int(seed)
        self.time_scale = _time_scale(time_scale)
        self.clock = ScaledClock(self.time_scale)
        self.platform = platform(preset, self.seed, dict(overrides or {}), clock=self.clock)
        self.serial = f"MCS2-TWIN-{self.seed}"
        self.mcs2_port, self.frames_port = int(mcs2_port), int(frames_port)
        self._max_connections = int(max_connections)
        self._max_lifetime_s = float(max_lifetime_s)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.mcs2 = _MCS2Peer(self.platform, self._lock, self.serial)
        info = {"format": INFO_FORMAT, "preset": preset, "seed": self.seed,
                "time_scale": self.time_scale}  # fmt: skip
        self.frames = _FramePeer(self.platform, self._lock, info)
        self._servers: list[_LineServer] = []
        self._started = False

    # --- lifetime ---------------------------------------------------------------------------
    def start(self) -> Self:
        """Listen on both ports (the actual ones are then :attr:`mcs2_port`, :attr:`frames_port`).

        Raises
        ------
        DeviceError
            A port cannot be listened on (in use, say); nothing is left listening.
        """
        if self._started:
            return self
        self._started = True
        deadline = time.monotonic() + self._max_lifetime_s
        peers = (("MCS2 peer", self.mcs2_port, self.mcs2.handle),
                 ("frame server", self.frames_port, self.frames.handle))  # fmt: skip
        for what, port, peer in peers:
            server = _LineServer(what, self.host, port, peer, self._stop, deadline,
                                 self._max_connections)  # fmt: skip
            try:
                server.start()
            except BaseException:
                self.close()
                raise
            self._servers.append(server)
        self.mcs2_port, self.frames_port = self._servers[0].port, self._servers[1].port
        return self

    def close(self) -> None:
        """Stop both servers and their connections (idempotent)."""
        self._stop.set()
        for server in self._servers:
            server.close()

    @property
    def closed(self) -> bool:
        """True once :meth:`close` was called (or the lifetime ran out)."""
        return self._stop.is_set()

    def __enter__(self) -> Self:
        return self.start()

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        self.close()

    def serve(
        self, duration_s: float | None = None, ready: Callable[[], None] | None = None
    ) -> str:
        """Block until ``duration_s`` passed, SIGTERM, Ctrl-C or :meth:`close`; say which.

        SIGTERM ends the wait only when called from the main thread (where the handler can
        be installed; the previous one is put back). ``ready`` is called once it is in place
        (say there that the twin is listening: a SIGTERM from then on stops it cleanly).

        Returns
        -------
        str
            ``"duration"``, ``"terminated"``, ``"interrupted"`` or ``"closed"``.
        """
        limit = self._max_lifetime_s
        if duration_s is not None:
            limit = min(max(0.0, float(duration_s)), limit)
        reason = ["duration"]

        def terminate(signum: int, frame: object) -> None:
            reason[0] = "terminated"
            self._stop.set()

        main = threading.current_thread() is threading.main_thread()
        previous = signal.signal(signal.SIGTERM, terminate) if main else None
        try:
            if ready is not None:
                ready()
            end = time.monotonic() + limit
            for _ in range(int(limit / 0.5) + 2):  # bounded: one wait of <= 0.5 s per turn
                left = end - time.monotonic()
                if left <= 0 or self._stop.wait(min(0.5, left)):
                    break
        except KeyboardInterrupt:
            reason[0] = "interrupted"
        finally:
            if main:
                signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
        if reason[0] == "duration" and self._stop.is_set():
            reason[0] = "closed"
        return reason[0]

    # --- the rig ----------------------------------------------------------------------------
    def rig_toml(self, rig_path: str = "twin.toml") -> str:
        """The rig file for the twin as started (its host and actual ports), to be saved as
        ``rig_path`` (named in its comments)."""
        return twin_rig_toml(self.platform, host=self.host, mcs2_port=self.mcs2_port,
                             frames_port=self.frames_port, preset=self.preset,
                             time_scale=self.time_scale, rig_path=rig_path)  # fmt: skip

    def describe(self) -> str:
        """One line: what listens where."""
        return (
            f"digital twin (preset {self.preset}, seed {self.seed}, time x{self.time_scale:g}): "
            f"SmarAct MCS2 {self.serial} on {self.host}:{self.mcs2_port}, frames of "
            f"{', '.join(self.platform.cameras)} on {self.host}:{self.frames_port}"
        )


def _toml_limits(limits_um: FloatArray) -> str:
    """The soft limits of the axes that move (a held axis, low == high, is left out)."""
    pairs = ", ".join(
        f"{axis} = [{float(lo)!r}, {float(hi)!r}]"
        for axis, (lo, hi) in zip("xyz", limits_um, strict=True)
        if hi > lo
    )
    return "{ " + pairs + " }"


def _toml_channels(first: int, limits_um: FloatArray) -> str:
    """Channels ``first``, ``first + 1``, ``first + 2`` for x, y, z; an X-Y positioner (z
    held) names x and y alone, as its rig file on hardware would."""
    pairs = ", ".join(
        f"{axis} = {first + k}"
        for k, (axis, (lo, hi)) in enumerate(zip("xyz", limits_um, strict=True))
        if hi > lo
    )
    return "{ " + pairs + " }"


def twin_rig_toml(
    plat: SimPlatform,
    *,
    host: str = "127.0.0.1",
    mcs2_port: int = MCS2_PORT,
    frames_port: int = FRAMES_PORT,
    preset: str = "thesis",
    time_scale: float = 1.0,
    rig_path: str = "twin.toml",
) -> str:
    """The hardware rig file that drives a twin of ``plat`` through the real drivers.

    The manipulator and the target stage are SmarAct MCS2 channels 0-2 and 3-5 at
    ``host:mcs2_port``, further devices (``[manipulators.NAME]``) the channels after, each
    with its simulated device's limits; the cameras are Micro-Manager devices of
    :mod:`microcal.devices.twin_camera` fed by the frame server at ``host:frames_port``, with
    the simulated cameras' pixel sizes. The comments say how to start the twin (``preset``,
    ``time_scale``) and check the rig (``rig_path``).

    Returns
    -------
    str
        TOML text (``formats.rig_file.load_rig`` reads it), starting with :data:`RIG_HEADER`.
    """
    start = "microcal twin" + (f" --preset {preset}" if preset != "thesis" else "")
    start += f" --seed {plat.seed}"
    if host != "127.0.0.1":
        start += f" --host {host}"
    if mcs2_port != MCS2_PORT:
        start += f" --port {mcs2_port}"
    if frames_port != FRAMES_PORT:
        start += f" --frames-port {frames_port}"
    if time_scale != 1.0:
        start += f" --time-scale {time_scale:g}"
    address = json.dumps(host)
    faster = ["# (--time-scale 10: simulated time runs ten times faster than the wall clock)"]
    faster = faster if time_scale == 1.0 else []
    lines = [
        RIG_HEADER,
        "# The simulated platform served through the real device protocols: the manipulator and",
        "# the target stage through the SmarAct MCS2 driver, the cameras through Micro-Manager.",
        "# Start the twin first, in another terminal (it runs until Ctrl-C):",
        f"#   {start}",
        *faster,
        "# then use this rig like any other, e.g. check it without moving anything:",
        f"#   microcal acquire --rig {rig_path} --out runs/a --dry-run",
        "# Needs: pip install 'microcal[mm]'  (see docs/hardware.md, 'The digital twin')",
        'driver = "hardware"',
        "# the chessboard on the end-effector, and the target on the target stage (the cameras",
        "# see the target while the stage was moved more recently than the manipulator)",
        f"board = {json.dumps(plat.config.board)}",
        f"calibration_target = {json.dumps(plat.config.calibration_target)}",
        "",
        "[manipulator]",
        'kind = "smaract-mcs2"',
        "# the twin's MCS2 peer: channels 0-2 move the manipulator, 3-5 the target stage",
        f"address = {address}",
        f"port = {mcs2_port}",
        "channels = { x = 0, y = 1, z = 2 }",
        "# soft limits, µm: the simulated manipulator's travel",
        f"limits_um = {_toml_limits(plat.manipulator.limits_um)}",
    ]
    if plat.target_stage is not None:
        lines += [
            "",
            "[target_stage]",
            "# the stage carrying the calibration target (stereo-calibrate --rig moves it)",
            'kind = "smaract-mcs2"',
            f"address = {address}",
            f"port = {mcs2_port}",
            "channels = { x = 3, y = 4, z = 5 }",
            f"limits_um = {_toml_limits(plat.target_stage.limits_um)}",
        ]
    further = [(n, m) for n, m in plat.manipulators.items() if n != "m1"]
    first = 6 if plat.target_stage is not None else 3
    for k, (name, device) in enumerate(further):
        c = first + 3 * k
        lines += [
            "",
            f"[manipulators.{name}]",
            f"# the twin's further device {name}: channels {c}-{c + 2}",
            'kind = "smaract-mcs2"',
            f"address = {address}",
            f"port = {mcs2_port}",
            f"channels = {_toml_channels(c, device.limits_um)}",
            f"limits_um = {_toml_limits(device.limits_um)}",
        ]
    lines += [
        "",
        "[micromanager]",
        "# pure-Python devices: one camera per simulated camera, frames from the twin",
        'python_devices = "microcal.devices.twin_camera:load"',
        f"options = {{ address = {address}, port = {frames_port} }}",
    ]
    for name, cam in plat.cameras.items():
        lines += [
            "",
            f"[cameras.{name}]",
            'kind = "micromanager"',
            f"device = {json.dumps(name)}",
            f"pixel_size_um = {cam.pixel_size_um!r}",
        ]
    return "\n".join(lines) + "\n"
