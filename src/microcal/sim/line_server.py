"""A TCP server of a line protocol on one loopback address: the digital twin's servers.

Each connection has its own thread, which answers every line it receives (ended by ``\\n``,
a ``\\r`` before it dropped) with what its peer's ``handle`` returns for it (None: no
answer). No client is trusted and none can hold the server: every read and every wait is
bounded (:class:`ServerLimits`; ``microcal.sim.twin.Twin`` takes the same names):

=====================  ==========================  ============================================
bound                  default                     beyond it
=====================  ==========================  ============================================
a request line         :data:`MAX_LINE_BYTES`,     the connection is dropped
                       4096 bytes
``max_clients``        :data:`MAX_CLIENTS`, 64     (clients at once) a new connection gets the
                                                   peer's busy line (``ERR busy ...`` from the
                                                   frame server; none from the MCS2 peer) and
                                                   is closed at once, never queued
``idle_timeout_s``     :data:`IDLE_TIMEOUT_S`,     a connection that sends no request line for
                       30 s                        this long (since its last request or answer)
                                                   is closed, freeing its slot; the bytes of a
                                                   line that never ends are no request
``request_timeout_s``  :data:`REQUEST_TIMEOUT_S`,  the request gets the peer's timeout answer
                       30 s                        (``ERR timeout ...`` from the frame server;
                                                   silence from the MCS2 peer, as from a
                                                   controller that does not answer)
sending one answer     30 s                        the connection is dropped
=====================  ==========================  ============================================

A peer bounds its own waits (for the platform's lock, for an exposure) by the request's
deadline, which it is given, and raises :class:`RequestTimeoutError` when it passes; an
answer that comes after the deadline anyway is replaced by the timeout answer. Every loop is
bounded: the server ends when its ``stop`` event is set or its deadline has passed.
"""

from __future__ import annotations

import contextlib
import math
import socket
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any, Protocol

from .._validation import check_number
from ..errors import DeviceError

__all__ = [
    "IDLE_TIMEOUT_S",
    "MAX_CLIENTS",
    "MAX_LINE_BYTES",
    "REQUEST_TIMEOUT_S",
    "LinePeer",
    "LineServer",
    "RequestTimeoutError",
    "ServerLimits",
    "held",
]

#: The longest request line a server takes, bytes.
MAX_LINE_BYTES = 4096
#: Connections a server holds at once by default (beyond them a connection is refused).
MAX_CLIENTS = 64
#: How long a connection may send no request by default before it is closed, s.
IDLE_TIMEOUT_S = 30.0
#: How long a request may take by default before it gets the timeout answer, s.
REQUEST_TIMEOUT_S = 30.0
_POLL_S = 0.2  # the servers' socket timeout: how soon they notice close() and idleness
_SEND_TIMEOUT_S = 30.0  # longest time to hand one answer (a frame) to a client


@dataclass(frozen=True)
class ServerLimits:
    """A server's bounds (the module's table).

    Raises
    ------
    InputError
        ``max_clients`` not a whole number >= 1, or a timeout not a finite number > 0.
    """

    max_clients: int = MAX_CLIENTS
    idle_timeout_s: float = IDLE_TIMEOUT_S
    request_timeout_s: float = REQUEST_TIMEOUT_S

    def __post_init__(self) -> None:
        clients = int(check_number("max_clients", self.max_clients, low=1, integer=True))
        object.__setattr__(self, "max_clients", clients)
        for name in ("idle_timeout_s", "request_timeout_s"):
            object.__setattr__(self, name, check_number(name, getattr(self, name), above=0))


class RequestTimeoutError(Exception):
    """A request's deadline passed before it was done (the server sends the timeout answer)."""


class LinePeer(Protocol):
    """What a :class:`LineServer` serves: the answers of one line protocol."""

    def handle(self, line: bytes, deadline: float = math.inf) -> bytes | None:
        """The answer to one request line (None: no answer); ``deadline`` is the
        ``time.monotonic()`` by which it must be done (:class:`RequestTimeoutError` after)."""
        ...

    def busy_answer(self, max_clients: int) -> bytes | None:
        """What a connection beyond ``max_clients`` is told before it is closed (None: no
        line)."""
        ...

    def timeout_answer(self, line: bytes, timeout_s: float) -> bytes | None:
        """The answer to a request that took longer than ``timeout_s`` (None: silence)."""
        ...


@contextlib.contextmanager
def held(lock: threading.Lock, deadline: float) -> Iterator[None]:
    """``lock`` held for the block if it can be had by ``deadline`` (``time.monotonic()``).

    Raises
    ------
    RequestTimeoutError
        The lock was not free in time.
    """
    left = deadline - time.monotonic()
    if not lock.acquire(timeout=-1 if math.isinf(left) else max(0.0, left)):
        raise RequestTimeoutError
    try:
        yield
    finally:
        lock.release()


class LineServer:
    """A TCP server on one address: a thread per connection, each answering its lines."""

    def __init__(
        self,
        what: str,
        host: str,
        port: int,
        peer: LinePeer,
        stop: threading.Event,
        deadline: float,
        limits: ServerLimits | None = None,
    ) -> None:
        self.what, self.host, self.port = what, host, port
        self.peer = peer
        self.stop = stop
        self.deadline = deadline
        self.limits = limits or ServerLimits()
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
            server.listen(min(socket.SOMAXCONN, self.limits.max_clients + 16))
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
            except TimeoutError:
                continue
            except OSError:  # out of descriptors, say: wait rather than spin
                self.stop.wait(_POLL_S)
                continue
            with self._guard:
                self._threads = [t for t in self._threads if t.is_alive()]
                full = len(self._clients) >= self.limits.max_clients
                if not full:
                    self._clients.add(conn)
            if full:
                self._refuse(conn)
                continue
            conn.settimeout(_POLL_S)
            self._spawn(self._serve, conn)

    def _refuse(self, conn: socket.socket) -> None:
        """Tell a connection beyond ``max_clients`` so (if the peer has a line for it) and
        close it, without waiting for it."""
        answer = self.peer.busy_answer(self.limits.max_clients)
        try:
            conn.setblocking(False)
            if answer is not None:
                conn.send(answer)
            conn.shutdown(socket.SHUT_WR)
            conn.recv(65536)  # what it sent already: the close then ends with no reset
        except OSError:
            pass
        finally:
            conn.close()

    def _serve(self, conn: socket.socket) -> None:
        buffer = b""
        quiet_since = time.monotonic()  # its last request line or answer
        try:
            while self.running():
                if time.monotonic() - quiet_since > self.limits.idle_timeout_s:
                    return  # idle: its slot is freed
                try:
                    chunk = conn.recv(65536)
                except TimeoutError:
                    continue
                if not chunk:
                    return
                *lines, buffer = (buffer + chunk).split(b"\n")
                for line in lines:
                    if len(line) > MAX_LINE_BYTES or not self.running():
                        return  # not a line of this protocol: drop the connection
                    self._answer(conn, line.rstrip(b"\r"))
                    quiet_since = time.monotonic()
                if len(buffer) > MAX_LINE_BYTES:
                    return
        except OSError:
            return
        finally:
            with self._guard:
                self._clients.discard(conn)
            conn.close()

    def _answer(self, conn: socket.socket, line: bytes) -> None:
        timeout_s = self.limits.request_timeout_s
        deadline = time.monotonic() + timeout_s
        try:
            answer = self.peer.handle(line, deadline)
            if time.monotonic() > deadline:
                raise RequestTimeoutError
        except RequestTimeoutError:
            answer = self.peer.timeout_answer(line, timeout_s)
        if answer is not None and self.running():
            conn.settimeout(_SEND_TIMEOUT_S)  # a frame: the whole of it
            conn.sendall(answer)
            conn.settimeout(_POLL_S)

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
