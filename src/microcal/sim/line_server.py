"""A TCP server of a line protocol on one loopback address: the digital twin's servers.

Each connection has its own thread, which answers every line it receives (ended by ``\n``,
a ``\r`` before it dropped) with what the server's ``handle`` returns for it (None: no
answer). A line longer than :data:`MAX_LINE_BYTES` drops the connection. Every loop is
bounded: the server ends when its ``stop`` event is set or its deadline has passed.
"""

from __future__ import annotations

import contextlib
import socket
import threading
import time
from collections.abc import Callable
from typing import Any

from ..errors import DeviceError

__all__ = ["MAX_LINE_BYTES", "LineServer"]

#: The longest request line a server takes, bytes.
MAX_LINE_BYTES = 4096
_POLL_S = 0.2  # the servers' socket timeout: how soon they notice close()
_SEND_TIMEOUT_S = 30.0  # longest time to hand one answer (a frame) to a client


class LineServer:
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
                if len(buffer) > MAX_LINE_BYTES:
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
