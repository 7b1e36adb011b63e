"""A fake SmarAct MCS2 controller: a TCP peer on loopback that speaks the ASCII command set.

It moves each channel at a finite speed, reports the state bits, keeps an error queue,
answers ``;``-chained commands on one line, and injects faults on request: a connection
dropped after a move command, answers delayed, a move that fails, a command refused with an
error code. Tests start it inside their own network namespace and stop it with ``close()``.
"""

from __future__ import annotations

import socket
import threading
import time
from dataclasses import dataclass, field

MOVING, CLOSED_LOOP, END_STOP, MOVEMENT_FAILED = 0x1, 0x2, 0x100, 0x800


@dataclass
class Channel:
    position_pm: float = 0.0
    target_pm: float = 0.0
    start_pm: float = 0.0
    start_s: float = 0.0
    speed_pm_s: float = 20e9  # 20 mm/s
    mode: int = 0
    failed: bool = False
    fail_at_s: float | None = None  # the move in progress fails at this instant

    def now_pm(self, t: float) -> float:
        if self.failed:
            return self.position_pm
        if self.fail_at_s is not None:
            t = min(t, self.fail_at_s)
        span = self.target_pm - self.start_pm
        duration = abs(span) / self.speed_pm_s
        if t - self.start_s >= duration or duration == 0:
            return self.target_pm
        return self.start_pm + span * (t - self.start_s) / duration

    def moving(self, t: float) -> bool:
        return not self.failed and (self.fail_at_s is not None or self.now_pm(t) != self.target_pm)


@dataclass
class Faults:
    drop_after_move: int = 0  # close the connection after this many more MOVE commands (0: never)
    delay_s: float = 0.0  # wait this long before every answer
    fail_move_channel: int | None = None  # the next move of this channel fails
    fail_after_moves: int = 0  # the move command this many commands from now fails (0: none)
    refuse_with: tuple[int, str] | None = None  # the next command is refused with this error
    silent: bool = False  # answer nothing at all
    endless: bool = False  # answer with bytes that never end in a line end


@dataclass
class FakeMCS2:
    """The fake controller; ``address``/``port`` once started."""

    n_channels: int = 3
    serial: str = "MCS2-FAKE0001"
    host: str = "127.0.0.1"
    port: int = 0
    channels: list[Channel] = field(default_factory=list)
    faults: Faults = field(default_factory=Faults)
    errors: list[tuple[int, str]] = field(default_factory=list)
    log: list[str] = field(default_factory=list)  # every command received
    connections: int = 0

    def __post_init__(self) -> None:
        self.channels = [Channel() for _ in range(self.n_channels)]
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._threads: list[threading.Thread] = []
        self._server: socket.socket | None = None
        self._clients: list[socket.socket] = []

    # --- lifetime -----------------------------------------------------------------------------
    def start(self) -> FakeMCS2:
        server = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        server.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        server.bind((self.host, self.port))
        server.listen(4)
        server.settimeout(0.1)
        self.port = server.getsockname()[1]
        self._server = server
        self._spawn(self._accept_loop)
        return self

    def close(self) -> None:
        self._stop.set()
        for c in list(self._clients):
            c.close()
        if self._server is not None:
            self._server.close()
        for t in self._threads:
            t.join(timeout=2.0)

    def __enter__(self) -> FakeMCS2:
        return self.start()

    def __exit__(self, *_exc: object) -> None:
        self.close()

    def _spawn(self, target, *args) -> None:
        t = threading.Thread(target=target, args=args, daemon=True)
        t.start()
        self._threads.append(t)

    def _accept_loop(self) -> None:
        assert self._server is not None
        while not self._stop.is_set():
            try:
                conn, _ = self._server.accept()
            except (TimeoutError, OSError):
                continue
            self.connections += 1
            conn.settimeout(0.1)
            self._clients.append(conn)
            self._spawn(self._serve, conn)

    def _serve(self, conn: socket.socket) -> None:
        buffer = b""
        with conn:
            while not self._stop.is_set():
                try:
                    chunk = conn.recv(4096)
                except TimeoutError:
                    continue
                except OSError:
                    return
                if not chunk:
                    return
                buffer += chunk
                while b"\r\n" in buffer:
                    line, _, buffer = buffer.partition(b"\r\n")
                    answer, drop = self.handle(line.decode("ascii"))
                    if self.faults.delay_s:
                        time.sleep(self.faults.delay_s)
                    if self.faults.endless:
                        try:
                            while not self._stop.is_set():
                                conn.sendall(b"0" * 65536)
                        except OSError:
                            return
                    if answer is not None and not self.faults.silent:
                        try:
                            conn.sendall(answer.encode("ascii") + b"\r\n")
                        except OSError:
                            return
                    if drop:
                        return

    # --- the command set ------------------------------------------------------------------------
    def handle(self, line: str) -> tuple[str | None, bool]:
        """Answer one line of ``;``-chained commands: (answer line or None, drop connection)."""
        answers, drop = [], False
        with self._lock:
            for part in line.split(";"):
                command = part.strip()
                if not command:
                    continue
                self.log.append(command)
                out, dropped = self._one(command)
                drop = drop or dropped
                if out is not None:
                    answers.append(out)
        return (";".join(answers) if answers else None), drop

    def _channel(self, text: str) -> Channel | None:
        try:
            n = int(text)
        except ValueError:
            return None
        return self.channels[n] if 0 <= n < len(self.channels) else None

    def _one(self, command: str) -> tuple[str | None, bool]:
        t = time.monotonic()
        if self.faults.refuse_with is not None and not command.endswith("?"):
            self.errors.append(self.faults.refuse_with)
            self.faults.refuse_with = None
            return None, False
        upper = command.upper()
        if upper == ":DEV:SNUM?":
            return f'"{self.serial}"', False
        if upper == ":SYST:ERR:NEXT?":
            code, message = self.errors.pop(0) if self.errors else (0, "No error")
            return f'{code},"{message}"', False
        if upper == ":SYST:ERR:COUN?":
            return str(len(self.errors)), False
        if upper.startswith(":MOVE"):
            head, _, value = command[5:].partition(" ")
            ch = self._channel(head)
            if ch is None or not value:
                self.errors.append((-221, "Settings conflict: invalid channel or value"))
                return None, False
            ch.start_pm, ch.start_s = ch.now_pm(t), t
            ch.position_pm = ch.start_pm
            ch.target_pm = float(int(value))
            ch.failed = False
            ch.fail_at_s = None
            countdown_hit = False
            if self.faults.fail_after_moves:
                self.faults.fail_after_moves -= 1
                countdown_hit = self.faults.fail_after_moves == 0
            if self.faults.fail_move_channel == int(head) or countdown_hit:
                # blocked 40 % of the way
                ch.fail_at_s = t + 0.4 * abs(ch.target_pm - ch.start_pm) / ch.speed_pm_s
                self.faults.fail_move_channel = None
            drop = False
            if self.faults.drop_after_move:
                self.faults.drop_after_move -= 1
                drop = self.faults.drop_after_move == 0
            return None, drop
        if upper.startswith(":STOP"):
            ch = self._channel(command[5:])
            if ch is None:
                self.errors.append((-221, "Settings conflict: invalid channel"))
                return None, False
            ch.position_pm = ch.target_pm = ch.start_pm = ch.now_pm(t)
            return None, False
        if upper.startswith(":CHAN"):
            head, _, rest = command[5:].partition(":")
            ch = self._channel(head)
            if ch is None:
                self.errors.append((-221, "Settings conflict: invalid channel"))
                return None, False
            key, _, value = rest.partition(" ")
            key = key.upper()
            if ch.fail_at_s is not None and t >= ch.fail_at_s:
                ch.position_pm = ch.now_pm(ch.fail_at_s)
                ch.failed, ch.fail_at_s = True, None
                self.errors.append((-1015, "Movement failed: blocked"))
            if key == "POS?":
                return str(round(ch.now_pm(t))), False
            if key == "STAT?":
                bits = CLOSED_LOOP
                bits |= MOVING if ch.moving(t) else 0
                bits |= MOVEMENT_FAILED if ch.failed else 0
                return str(bits), False
            if key == "MMOD":
                ch.mode = int(value)
                return None, False
            if key == "MMOD?":
                return str(ch.mode), False
            if key == "VEL":
                ch.speed_pm_s = float(value)
                return None, False
            if key == "VEL?":
                return str(round(ch.speed_pm_s)), False
        self.errors.append((-113, "Undefined header"))
        return None, False
