"""The digital twin's SmarAct MCS2 peer: the controller over the simulated platform's devices.

:mod:`microcal.sim.twin` serves it on ``mcs2_port`` (the controller's standard port,
:data:`~microcal.devices.smaract_mcs2.MCS2_PORT`, by default).

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

The server's bounds (clients, idle time, request time, line length) are
:mod:`microcal.sim.line_server`'s. The controller's protocol has no line for them: a
connection beyond the clients at once is closed without one, and a request that cannot be
done within the request timeout (the platform's lock held that long) is silence, as a
controller that does not answer, which the driver reports as a timeout.
"""

from __future__ import annotations

import math
import threading
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any

from ..devices.base import Clock
from ..devices.smaract_mcs2 import PM_PER_UM, STATE_BITS
from ..devices.twin_protocol import ascii_message
from ..errors import DeviceTimeoutError, LimitError, MicrocalError, MoveError
from .line_server import held
from .manipulator import SimManipulator
from .platforms import SimPlatform
from .stage import SimStage

__all__ = ["MAX_COMMANDS_PER_LINE", "MCS2Peer", "SimDevice", "mcs2_devices"]

#: The commands of one line that are answered (the rest is ignored).
MAX_COMMANDS_PER_LINE = 32
_MOVING, _CLOSED_LOOP = STATE_BITS["moving"], STATE_BITS["closed_loop"]
# the controller's error codes (SCPI's where it has one)
ERR_DATA_TYPE = -104
ERR_UNDEFINED_HEADER = -113
ERR_SETTINGS_CONFLICT = -221
ERR_OUT_OF_RANGE = -222
ERR_DEVICE = -300
ERR_MOVEMENT_FAILED = -1015

SimDevice = SimManipulator | SimStage


def mcs2_devices(plat: SimPlatform) -> list[tuple[str, SimDevice]]:
    """The devices behind the peer's channels, by name, in order: device k has channels
    3k, 3k + 1, 3k + 2 (x, y, z): the manipulator ``m1``, the target stage
    (``target_stage``, if any), then the further devices (``m2``, ``p1``, ...)."""
    devices: list[tuple[str, SimDevice]] = [("m1", plat.manipulator)]
    if plat.target_stage is not None:
        devices.append(("target_stage", plat.target_stage))
    devices += [(name, m) for name, m in plat.manipulators.items() if name != "m1"]
    return devices


class _NoAnswerError(Exception):
    """The line gets no answer (a simulated timeout)."""


class MCS2Peer:
    """The controller's command set over simulated devices: device k on channels 3k to
    3k + 2 (a platform's: :func:`mcs2_devices`; the ``patch`` preset's: its manipulator)."""

    def __init__(
        self, devices: Sequence[SimDevice], clock: Clock, lock: threading.Lock, serial: str
    ) -> None:
        self.lock = lock
        self.serial = serial
        self.devices = list(devices)
        now = clock.now_s()
        #: Per device, the joint targets last commanded, (3,) µm.
        self.targets = [d.joints_um(now).copy() for d in self.devices]
        self.modes = [0] * (3 * len(self.devices))
        self.errors: deque[tuple[int, str]] = deque(maxlen=64)
        self.log: deque[str] = deque(maxlen=1000)  # the last commands received (for tests)
        self.clock = clock

    def handle(self, line: bytes, deadline: float = math.inf) -> bytes | None:
        """The answer line to one line of ``;``-chained commands (None: no answer).

        Raises
        ------
        RequestTimeoutError
            The platform's lock was not free by ``deadline`` (``time.monotonic()``).
        """
        text = line.decode("ascii", errors="replace")
        answers = []
        with held(self.lock, deadline):
            try:
                for part in text.split(";")[:MAX_COMMANDS_PER_LINE]:
                    command = part.strip()
                    if command:
                        self.log.append(command)
                        out = self._one(command)
                        if out is not None:
                            answers.append(out)
            except _NoAnswerError:
                return None
        return (";".join(answers) + "\r\n").encode("ascii") if answers else None

    def busy_answer(self, max_clients: int) -> None:
        """None: a connection beyond the clients at once is closed without a line."""
        return None

    def timeout_answer(self, line: bytes, timeout_s: float) -> None:
        """None: a request beyond the request timeout is not answered (the driver times out)."""
        return None

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
            self.errors.append((ERR_OUT_OF_RANGE, ascii_message(f"Data out of range: {exc}")))
        except MoveError as exc:
            self.errors.append((ERR_MOVEMENT_FAILED, ascii_message(f"Movement failed: {exc}")))
        except MicrocalError as exc:
            self.errors.append((ERR_DEVICE, ascii_message(f"Device-specific error: {exc}")))
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
        self.errors.append(
            (ERR_UNDEFINED_HEADER, f"Undefined header: {ascii_message(command)[:40]}")
        )
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
            return str(_CLOSED_LOOP | (_MOVING if moving else 0))
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
