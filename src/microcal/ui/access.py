"""Who may use the station page, and who may move the manipulator.

- **The token.** On loopback (the default) the page needs none: only this machine's users
  reach it. Opened to the lab network (``--host``), every request needs the token printed
  once at start, in the URL (``?token=...``); the page then keeps it in a cookie that only
  this site sees. Without it: refused.
- **Requests from other sites.** A request must name this server as its ``Host`` (so a
  hostile name that resolves to 127.0.0.1 is refused), a request that changes anything must
  be JSON and, where the browser says its ``Origin``, come from this page: a page of another
  site cannot move the manipulator through the user's browser.
- **One controlling browser.** The first browser to claim control keeps it while it polls
  (a lease renewed by each poll); every other browser watches: it sees everything and may
  press stop, but its moves are refused. A controller that goes away (its page closed)
  loses control after :data:`LEASE_S`.
"""

from __future__ import annotations

import ipaddress
import secrets
import threading
import time

__all__ = [
    "CLIENT_COOKIE",
    "LEASE_S",
    "TOKEN_COOKIE",
    "Control",
    "is_loopback",
    "new_token",
    "token_matches",
]

CLIENT_COOKIE = "microcal_client"
TOKEN_COOKIE = "microcal_token"
#: A controller that has not polled for this long loses control, s.
LEASE_S = 5.0


def is_loopback(host: str) -> bool:
    """True for an address or name that only this machine reaches (127.0.0.0/8, ::1,
    localhost)."""
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:
        return False


def new_token() -> str:
    """A fresh random token (32 bytes, URL-safe)."""
    return secrets.token_urlsafe(32)


def token_matches(given: str | None, token: str) -> bool:
    """True when ``given`` is the token (compared in constant time)."""
    return given is not None and secrets.compare_digest(given.encode(), token.encode())


class Control:
    """The controlling browser's lease (thread-safe).

    Parameters
    ----------
    lease_s : float
        How long a controller keeps control without polling.
    clock : callable () -> float
        Monotonic time, s (a test's own clock).
    """

    def __init__(self, lease_s: float = LEASE_S, clock: object = time.monotonic) -> None:
        self.lease_s = float(lease_s)
        self._clock = clock
        self._holder: str | None = None
        self._seen = 0.0
        self._lock = threading.Lock()

    def _now(self) -> float:
        return float(self._clock())  # type: ignore[operator]

    def _expired(self) -> bool:
        return self._holder is None or self._now() - self._seen > self.lease_s

    def claim(self, client: str) -> bool:
        """Take control if nobody holds it (or the holder's lease ran out); True if ``client``
        now controls."""
        with self._lock:
            if self._holder == client or self._expired():
                self._holder, self._seen = client, self._now()
            return self._holder == client

    def renew(self, client: str) -> bool:
        """Called on each poll: True if ``client`` controls (its lease renewed)."""
        with self._lock:
            if self._holder == client and not self._expired():
                self._seen = self._now()
                return True
            return False

    def controls(self, client: str | None) -> bool:
        """True if ``client`` holds a live lease."""
        with self._lock:
            return client is not None and self._holder == client and not self._expired()

    def held(self) -> bool:
        """True if some browser controls."""
        with self._lock:
            return not self._expired()

    def release(self, client: str) -> None:
        """Give control up (a page closing)."""
        with self._lock:
            if self._holder == client:
                self._holder = None
