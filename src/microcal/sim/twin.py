"""The digital twin: the simulated platform served through the real devices' protocols.

One process holds a simulated platform (:func:`microcal.sim.platform`) on a clock that
follows the wall clock (:class:`~microcal.sim.scaled_clock.ScaledClock`), and serves it on
loopback, so that microcal's hardware drivers drive it exactly as they drive a rig: the
SmarAct MCS2 driver talks to the manipulator and the target stage, and the Micro-Manager
bridge grabs the cameras' frames through pure-Python devices
(:mod:`microcal.devices.twin_camera`). Moves take their time, the end-effector creeps and
drifts, and a frame takes its exposure and readout, all ``time_scale`` times faster than in
real time.

Start it with ``microcal twin`` (or :class:`Twin` from Python) and open the rig file it
writes (``microcal.formats.twin_rig_file.twin_rig_toml`` of :meth:`Twin.rig_description`;
``examples/rigs/twin.toml`` for the default ports).

It serves two peers, each a line protocol on a server of its own
(:class:`~microcal.sim.line_server.LineServer`):

- the MCS2 peer (``mcs2_port``, 55551 by default): the controller's ASCII interface,
  :mod:`microcal.sim.mcs2_peer` (its docstring has the command table);
- the frame server (``frames_port``, 55561 by default): the cameras,
  :mod:`microcal.sim.frame_server`, speaking :mod:`microcal.devices.twin_protocol` (its
  docstring has the protocol table).

``--preset patch`` serves the one-camera microscope instead (:mod:`microcal.sim.patch_twin`):
its camera, X-Y stage and focus drive on the frame server (Micro-Manager devices on the
other side: :mod:`microcal.devices.twin_camera`, :mod:`microcal.devices.twin_stages`), its
pipette's manipulator on the MCS2 peer.

Every access to the platform holds one lock, except a frame's exposure, waited out after
the frame is rendered (:mod:`microcal.sim.frame_server`): a long exposure holds up no other
device. Each connection has its own thread. No client is trusted: each server bounds a
request line's length (4096 bytes), its clients at once (``max_clients``, 64), a
connection's idle time (``idle_timeout_s``, 30 s) and a request's time
(``request_timeout_s``, 30 s); :mod:`microcal.sim.line_server` says what happens beyond each.
Every loop is bounded: the servers end with :meth:`Twin.close` or after ``max_lifetime_s``.
"""

from __future__ import annotations

import ipaddress
import signal
import threading
import time
from collections.abc import Callable, Mapping
from types import TracebackType
from typing import Any, Self

from ..devices.base import Clock
from ..devices.smaract_mcs2 import MCS2_PORT
from ..devices.twin_protocol import FRAMES_PORT
from ..errors import InputError
from .frame_server import FramePeer
from .line_server import (
    IDLE_TIMEOUT_S,
    MAX_CLIENTS,
    REQUEST_TIMEOUT_S,
    LinePeer,
    LineServer,
    ServerLimits,
)
from .mcs2_peer import MCS2Peer, SimDevice, mcs2_devices
from .patch import PATCH_PRESET, PatchConfig, PatchRig
from .patch_twin import PatchFramePeer, check_sample, patch_twin_rig
from .platforms import SimPlatform, platform
from .scaled_clock import ScaledClock
from .twin_rig import TwinRig, twin_rig

__all__ = ["MAX_LIFETIME_S", "Twin"]

#: How long the servers live at most, s (every loop is bounded in time).
MAX_LIFETIME_S = 7 * 24 * 3600.0


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
        The simulated platform (:func:`microcal.sim.platform`); preset ``patch`` is the
        one-camera microscope (:mod:`microcal.sim.patch_twin`: its camera, X-Y stage and
        focus on the frame server, its manipulator on the MCS2 peer; no overrides).
    host : str
        A loopback address to listen on.
    mcs2_port, frames_port : int
        TCP ports of the MCS2 peer and the frame server (0: any free port).
    time_scale : float
        Simulated seconds per wall second (:class:`ScaledClock`).
    max_clients : int
        Connections each server holds at once (64); a further one is refused at once (told
        ``ERR busy ...`` by the frame server) and closed.
    idle_timeout_s : float
        A connection that sends no request for this long is closed (30 s).
    request_timeout_s : float
        A request taking longer gets the timeout answer (30 s): ``ERR timeout ...`` from the
        frame server, none from the MCS2 peer.
    max_lifetime_s : float
        The servers stop by themselves after this long, s.
    clock : Clock, optional
        The simulated devices' clock instead of the scaled clock (for comparisons run in
        one process: a :class:`~microcal.sim.clock.SimClock`, shared with the client, makes
        simulated time pass only by the devices' waits and the client's, as in the
        in-process simulator; a frame's exposure is then waited out under the lock).

    Attributes
    ----------
    platform : SimPlatform or None
        The simulated platform (its ``truth_*`` for tests); None for ``patch``.
    patch : PatchRig or None
        The ``patch`` preset's rig (its truth for tests); None for a platform.
    serial : str
        The MCS2 peer's serial number, ``MCS2-TWIN-<seed>``.
    limits : ServerLimits
        The servers' bounds (``max_clients``, ``idle_timeout_s``, ``request_timeout_s``).

    Raises
    ------
    InputError
        A host that is not loopback, a ``max_clients`` that is not a whole number >= 1, or
        a timeout that is not a finite number > 0.
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
        max_clients: int = MAX_CLIENTS,
        idle_timeout_s: float = IDLE_TIMEOUT_S,
        request_timeout_s: float = REQUEST_TIMEOUT_S,
        max_lifetime_s: float = MAX_LIFETIME_S,
        clock: Clock | None = None,
        sample: str = "tissue",
    ) -> None:
        self.host = _check_host(host)
        self.limits = ServerLimits(max_clients, idle_timeout_s, request_timeout_s)
        self.preset, self.seed = preset, int(seed)
        scaled = ScaledClock(time_scale)
        self.time_scale = scaled.time_scale
        self.clock: Clock = scaled if clock is None else clock
        self.serial = f"MCS2-TWIN-{self.seed}"
        self.mcs2_port, self.frames_port = int(mcs2_port), int(frames_port)
        self._max_lifetime_s = float(max_lifetime_s)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.platform: SimPlatform | None = None
        self.patch: PatchRig | None = None
        self.frames: FramePeer
        if preset == PATCH_PRESET:
            if overrides:
                raise InputError(
                    "overrides: the twin serves the patch preset as it is (no overrides); "
                    "leave them out"
                )
            check_sample(sample)
            self.patch = PatchRig(PatchConfig(), self.seed, clock=self.clock)
            devices: list[SimDevice] = [self.patch.manipulator]
            self.frames = PatchFramePeer(self.patch, self._lock, seed=self.seed,
                                         time_scale=self.time_scale, stop=self._stop,
                                         sample=sample)  # fmt: skip
        else:
            if sample != "tissue":
                raise InputError(
                    f"sample {sample!r}: only the patch preset has a sample to change; "
                    "add --preset patch"
                )
            self.platform = platform(preset, self.seed, dict(overrides or {}), clock=self.clock)
            devices = [d for _, d in mcs2_devices(self.platform)]
            self.frames = FramePeer(self.platform, self._lock, preset=preset, seed=self.seed,
                                    time_scale=self.time_scale, stop=self._stop)  # fmt: skip
        self.mcs2 = MCS2Peer(devices, self.clock, self._lock, self.serial)
        self._servers: list[LineServer] = []
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
        peers: tuple[tuple[str, int, LinePeer], ...] = (
            ("MCS2 peer", self.mcs2_port, self.mcs2),
            ("frame server", self.frames_port, self.frames),
        )
        for what, port, peer in peers:
            server = LineServer(what, self.host, port, peer, self._stop, deadline, self.limits)
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
    def rig_description(self) -> TwinRig:
        """The twin as started (its host and actual ports), for its rig file
        (``microcal.formats.twin_rig_file.twin_rig_toml`` writes it)."""
        if self.patch is not None:
            return patch_twin_rig(
                self.patch, host=self.host, mcs2_port=self.mcs2_port,
                frames_port=self.frames_port, time_scale=self.time_scale,
            )  # fmt: skip
        assert self.platform is not None  # a twin serves a platform or the patch rig
        return twin_rig(self.platform, host=self.host, mcs2_port=self.mcs2_port,
                        frames_port=self.frames_port, preset=self.preset,
                        time_scale=self.time_scale)  # fmt: skip

    @property
    def sample(self) -> str:
        """What lies on the patch rig's stage (``tissue`` or ``slide``; ``tissue`` for a
        platform)."""
        return self.frames.camera.sample if isinstance(self.frames, PatchFramePeer) else "tissue"

    @sample.setter
    def sample(self, value: str) -> None:
        if not isinstance(self.frames, PatchFramePeer):
            raise InputError(f"sample {value!r}: only the patch preset has a sample to change")
        with self._lock:
            self.frames.camera.sample = check_sample(value)

    def describe(self) -> str:
        """One line: what listens where."""
        return (
            f"digital twin (preset {self.preset}, seed {self.seed}, time x{self.time_scale:g}): "
            f"SmarAct MCS2 {self.serial} on {self.host}:{self.mcs2_port}, frames of "
            f"{', '.join(self.frames.cameras)} on {self.host}:{self.frames_port}"
            + (f", stages {', '.join(self.frames.stages)}" if self.frames.stages else "")
            + self._sample_note()
        )

    def _sample_note(self) -> str:
        if not isinstance(self.frames, PatchFramePeer) or self.sample != "slide":
            return ""
        return f"; on the stage the slide {self.frames.camera.slide.target.spec}"
