"""A simulated clock: sleeping advances simulated time at once, so a 30 s settle costs nothing."""

from __future__ import annotations

from ..devices.base import Clock
from ..errors import InputError

__all__ = ["SimClock"]


class SimClock(Clock):
    """Simulated time in seconds, starting at ``start_s``."""

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = float(start_s)

    def now_s(self) -> float:
        return self._t

    def sleep(self, duration_s: float) -> None:
        if duration_s < 0:
            raise InputError(f"sleep: expected a duration >= 0 s, got {duration_s}")
        self._t += float(duration_s)
