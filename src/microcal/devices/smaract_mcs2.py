"""SmarAct MCS2 controller over TCP: its ASCII (SCPI-like) command set, one channel per axis.

The protocol, as used here (port 55551, lines end in ``\\r\\n``; linear positions in pm):

==========================  ===============================================================
``:DEV:SNUM?``              the controller's serial number (asked on connecting)
``:CHANn:MMOD 0``           channel n moves in closed-loop absolute mode
``:CHANn:VEL v``            channel n's speed, pm/s (optional)
``:MOVEn p``                start an absolute move of channel n to p pm
``:STOPn``                  stop channel n
``:CHANn:POS?``             position of channel n, pm
``:CHANn:STAT?``            state bits of channel n: 0x1 moving, 0x100 end stop,
                            0x400 following limit, 0x800 movement failed
``:SYST:ERR:NEXT?``         the oldest entry of the error queue: ``code,"message"``
                            (``0,"No error"`` when empty)
==========================  ===============================================================

Commands that set something have no answer; the driver chains ``;:SYST:ERR:NEXT?`` to each,
so every command has one answer line that says whether the controller accepted it.

A lost connection is opened again and the exchange repeated (queries and absolute moves are
idempotent); a controller that does not answer within ``timeout_s`` raises
:class:`DeviceTimeoutError`; a controller error, a failed movement, an end stop or a
following error raise :class:`MoveError` / :class:`DeviceError` naming the channel and the
controller's message.
"""

from __future__ import annotations

import socket
import time
from collections.abc import Mapping
from typing import Self

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray
from ..errors import DeviceError, DeviceTimeoutError, InputError, MoveError
from .base import Manipulator

__all__ = ["MAX_ANSWER_BYTES", "MCS2_PORT", "STATE_BITS", "MCS2Manipulator"]

MCS2_PORT = 55551
#: Longest answer line the driver reads, bytes (the longest real answer is an error message of
#: about a hundred); a peer that sends more without a line end is not an MCS2.
MAX_ANSWER_BYTES = 4096
PM_PER_UM = 1_000_000
#: Channel state bits the driver reads (:CHANn:STAT?).
STATE_BITS = {
    "moving": 0x1,
    "closed_loop": 0x2,
    "end_stop": 0x100,
    "following_limit": 0x400,
    "movement_failed": 0x800,
}
_FAULTS = {
    STATE_BITS["movement_failed"]: "movement failed",
    STATE_BITS["end_stop"]: "end stop reached",
    STATE_BITS["following_limit"]: "following error limit exceeded",
}


class MCS2Manipulator(Manipulator):
    """A manipulator driven by a SmarAct MCS2 controller, one channel per axis.

    Call :meth:`connect` first (``with MCS2Manipulator(...) as m:`` connects and closes);
    :meth:`close` closes the connection for good, while a connection lost in between is
    opened again by the next command.

    Parameters
    ----------
    address : str
        The controller's IP address or host name (no discovery is done).
    channels : mapping axis -> int
        Controller channel of each axis, e.g. ``{"x": 0, "y": 1, "z": 2}``; the mapping's
        order is the joint order.
    limits_um : (n_axes, 2) float
        Soft limits per axis, µm; checked before anything is sent.
    port : int
        TCP port (the controller's default 55551).
    timeout_s : float
        Longest wait for one answer.
    reconnects : int
        How many times a lost connection is opened again before giving up.
    speed_um_s : float, optional
        Channel speed to set on connecting (the controller's own setting if None).
    """

    def __init__(
        self,
        address: str,
        channels: Mapping[str, int],
        limits_um: ArrayLike,
        *,
        port: int = MCS2_PORT,
        name: str = "mcs2",
        timeout_s: float = 2.0,
        reconnects: int = 2,
        speed_um_s: float | None = None,
    ) -> None:
        if not channels:
            raise InputError("channels: expected a channel per axis, e.g. {x = 0, y = 1, z = 2}")
        super().__init__(name, tuple(channels), limits_um)
        self.address = address
        self.port = int(port)
        self.channels = tuple(int(c) for c in channels.values())
        self.timeout_s = float(timeout_s)
        self.reconnects = int(reconnects)
        self.speed_um_s = speed_um_s
        self.serial = ""
        self._sock: socket.socket | None = None
        self._buffer = b""
        self._connected = False
        self.reconnections = 0  # connections opened again after a loss (for the journal)

    @property
    def identity(self) -> str:
        """``SmarAct MCS2 <serial> channels 0,1,2`` (the serial once connected)."""
        return f"SmarAct MCS2 {self.serial} channels {','.join(map(str, self.channels))}"

    # --- connection -----------------------------------------------------------------------
    def connect(self) -> None:
        """Open the connection and set every channel to closed-loop absolute moves.

        Raises
        ------
        DeviceError
            The controller cannot be reached or refuses the setup, or the driver is closed.
        """
        self._check_open("connect")
        self._open()
        self.serial = self._query(":DEV:SNUM?").strip('"')
        self._drain_errors()
        for ch in self.channels:
            self._command(f":CHAN{ch}:MMOD 0")
            if self.speed_um_s is not None:
                self._command(f":CHAN{ch}:VEL {round(self.speed_um_s * PM_PER_UM)}")
        self._connected = True

    def _close(self) -> None:
        """Close the connection for good (the controller keeps its state)."""
        self._disconnect()

    def _disconnect(self) -> None:
        """Drop the socket (a lost or confused connection); the next exchange opens it again."""
        if self._sock is not None:
            try:
                self._sock.close()
            finally:
                self._sock = None
                self._buffer = b""

    def __enter__(self) -> Self:
        """Connect (unless :meth:`connect` was called already); :meth:`close` on leaving."""
        if not self._connected:
            try:
                self.connect()
            except BaseException:
                self.close()
                raise
        return self

    def _open(self) -> None:
        self._disconnect()
        try:
            self._sock = socket.create_connection((self.address, self.port), self.timeout_s)
        except TimeoutError:
            raise DeviceTimeoutError(
                f"{self.name}: no answer from {self.address}:{self.port} within "
                f"{self.timeout_s:g} s; is the controller on and the address right?"
            ) from None
        except OSError as exc:
            raise DeviceError(
                f"{self.name}: cannot connect to {self.address}:{self.port} ({exc.strerror or exc})"
            ) from None
        self._sock.settimeout(self.timeout_s)

    def _exchange(self, line: str) -> str:
        """Send one line and read one answer line; no retry."""
        self._check_open(f"command {line!r}")
        if self._sock is None:
            self._open()
        assert self._sock is not None
        self._sock.sendall(line.encode("ascii") + b"\r\n")
        deadline = time.monotonic() + self.timeout_s
        while b"\r\n" not in self._buffer:
            if time.monotonic() > deadline:
                raise TimeoutError
            chunk = self._sock.recv(4096)
            if not chunk:
                raise ConnectionError("closed by the controller")
            self._buffer += chunk
            if b"\r\n" not in self._buffer and len(self._buffer) > MAX_ANSWER_BYTES:
                self._disconnect()
                raise DeviceError(
                    f"{self.name}: the answer to {line!r} runs past {MAX_ANSWER_BYTES} bytes "
                    f"without a line end; is {self.address}:{self.port} an MCS2 controller?"
                )
        answer, _, self._buffer = self._buffer.partition(b"\r\n")
        return answer.decode("ascii", errors="replace").strip()

    def _transact(self, line: str) -> str:
        """One exchange; a lost connection is opened again and the line sent again."""
        for attempt in range(self.reconnects + 1):
            try:
                return self._exchange(line)
            except TimeoutError:
                self._disconnect()  # a late answer would pair with the next question
                raise DeviceTimeoutError(
                    f"{self.name}: no answer to {line!r} within {self.timeout_s:g} s"
                ) from None
            except (ConnectionError, OSError) as exc:
                self._disconnect()
                if attempt == self.reconnects:
                    raise DeviceError(
                        f"{self.name}: connection to {self.address}:{self.port} lost "
                        f"({exc}); gave up after {self.reconnects} reconnection(s)"
                    ) from None
                self.reconnections += 1
                self._open()
        raise AssertionError("unreachable")

    # --- commands ---------------------------------------------------------------------------
    def _query(self, query: str) -> str:
        return self._transact(query)

    def _command(self, command: str, error: type[DeviceError] = DeviceError) -> None:
        answer = self._transact(f"{command};:SYST:ERR:NEXT?")
        code, message = _parse_error(answer)
        if code != 0:
            raise error(f"{self.name}: controller error {code} ({message}) after {command!r}")

    def _drain_errors(self, limit: int = 64) -> list[tuple[int, str]]:
        """Read the error queue empty (bounded); returns the entries."""
        out = []
        for _ in range(limit):
            code, message = _parse_error(self._query(":SYST:ERR:NEXT?"))
            if code == 0:
                break
            out.append((code, message))
        return out

    def errors(self) -> list[tuple[int, str]]:
        """The controller's pending errors (code, message), oldest first; empties the queue."""
        return self._drain_errors()

    def _move(self, d_um: FloatArray) -> None:
        for ch, d in zip(self.channels, d_um, strict=True):
            self._command(f":MOVE{ch} {round(float(d) * PM_PER_UM)}", MoveError)

    def _position_um(self) -> FloatArray:
        values = [self._query(f":CHAN{ch}:POS?") for ch in self.channels]
        try:
            return np.array([float(v) / PM_PER_UM for v in values])
        except ValueError:
            raise DeviceError(f"{self.name}: position answers {values} are not numbers") from None

    def state(self, channel: int) -> int:
        """The state bits of one controller channel."""
        answer = self._query(f":CHAN{channel}:STAT?")
        try:
            return int(answer)
        except ValueError:
            raise DeviceError(
                f"{self.name}: state of channel {channel} is {answer!r}, not a number"
            ) from None

    def _is_moving(self) -> bool:
        moving = False
        for axis, ch in zip(self.axes, self.channels, strict=True):
            bits = self.state(ch)
            for bit, what in _FAULTS.items():
                if bits & bit:
                    queued = self._drain_errors()
                    detail = f"; controller: {queued[0][0]} ({queued[0][1]})" if queued else ""
                    raise MoveError(f"{self.name}: axis {axis} (channel {ch}): {what}{detail}")
            moving = moving or bool(bits & STATE_BITS["moving"])
        return moving

    def _stop(self) -> None:
        for ch in self.channels:
            self._command(f":STOP{ch}")


def _parse_error(answer: str) -> tuple[int, str]:
    code, _, message = answer.partition(",")
    try:
        return int(code), message.strip().strip('"')
    except ValueError:
        raise DeviceError(f"unexpected answer {answer!r} to the error query") from None
