"""Serve the station page: open the rig, build the application, run it until interrupted."""

from __future__ import annotations

import contextlib
import errno
import socket
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

from ..errors import InputError
from ..workflows.live import LiveStation, open_live_station
from .access import is_loopback, new_token
from .app import create_app

__all__ = ["DEFAULT_PORT", "StationServer", "serve", "start_server"]

DEFAULT_PORT = 8765


@dataclass
class StationServer:
    """A running station page: its address (with the token, if any) and how to stop it."""

    url: str
    token: str | None
    live: LiveStation
    server: Any  # uvicorn.Server
    thread: threading.Thread | None = None  # when started by start_server

    def stop(self) -> None:
        """Stop serving, stop any move and close the rig."""
        self.server.should_exit = True
        if self.thread is not None:
            self.thread.join(10.0)
        self.live.close()


def _bind(host: str, port: int) -> socket.socket:
    family = socket.AF_INET6 if ":" in host else socket.AF_INET
    sock = socket.socket(family, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    try:
        sock.bind((host, port))
    except OSError as exc:
        sock.close()
        busy = exc.errno == errno.EADDRINUSE
        raise InputError(
            f"--host {host} --port {port}: cannot listen there ({exc.strerror or exc})"
            + ("; another port, or --port 0 for any free one" if busy else "")
        ) from None
    sock.listen(64)
    return sock


def _prepare(live: LiveStation, host: str, port: int) -> tuple[Any, socket.socket, str, str | None]:
    """The server, its listening socket, the address to print and the token (None on
    loopback, where the ``Host`` header is checked instead: see :mod:`.access`)."""
    import uvicorn

    if not 0 <= port <= 65535:
        raise InputError(f"--port: expected 0 to 65535, got {port}")
    loopback = is_loopback(host)
    token = None if loopback else new_token()
    sock = _bind(host, port)
    bound = sock.getsockname()[1]
    shown = socket.gethostname() if host in ("0.0.0.0", "::", "") else host
    shown = f"[{shown}]" if ":" in shown else shown
    hosts = frozenset({f"{shown}:{bound}", f"localhost:{bound}"}) if loopback else frozenset()
    app = create_app(live, token, hosts)
    config = uvicorn.Config(app, log_level="warning", access_log=False, lifespan="off")
    url = f"http://{shown}:{bound}/" + (f"?token={token}" if token else "")
    return uvicorn.Server(config), sock, url, token


def start_server(live: LiveStation, host: str = "127.0.0.1", port: int = 0) -> StationServer:
    """Serve ``live`` in a thread of this process (tests, benchmarks); ``port`` 0 takes a
    free one. Stop it with :meth:`StationServer.stop`."""
    server, sock, url, token = _prepare(live, host, port)
    thread = threading.Thread(
        target=server.run,
        kwargs={"sockets": [sock]},
        daemon=True,
        name="microcal-ui-server",
    )
    thread.start()
    deadline = time.monotonic() + 10.0
    while not getattr(server, "started", False):
        if time.monotonic() > deadline or not thread.is_alive():
            raise InputError("ui: the server did not start within 10 s")
        time.sleep(0.01)
    return StationServer(url, token, live, server, thread)


def serve(
    rig: str,
    calibration: str,
    *,
    host: str = "127.0.0.1",
    port: int = DEFAULT_PORT,
    manipulator: str | None = None,
    seed: int | None = None,
    frames: int = 5,
    announce: Callable[[str], None] = print,
) -> None:
    """Open the rig and serve its page until interrupted (Ctrl-C, which returns normally after
    any move is stopped and the rig closed); ``announce`` is given the address (with the token
    when ``host`` is not loopback) once the server listens."""
    live = open_live_station(rig, calibration, manipulator=manipulator, seed=seed, frames=frames)
    try:
        server, sock, url, _ = _prepare(live, host, port)
        announce(url)
        with contextlib.suppress(KeyboardInterrupt):  # Ctrl-C is how the page is stopped
            server.run(sockets=[sock])
    finally:
        live.close()
