"""A simulated clock: sleeping advances simulated time at once, so a 30 s settle costs nothing."""

from __future__ import annotations

from ..devices.base import Clock

__all__ = ["SimClock"]


class SimClock(Clock):
    """Simulated time in seconds, starting at ``start_s``.

    :meth:`sleep` refuses negative and non-finite durations like every clock
    (:class:`~microcal.devices.base.Clock`).
    """

    def __init__(self, start_s: float = 0.0) -> None:
        self._t = float(start_s)

    def now_s(self) -> float:
        return self._t

    def _sleep(self, duration_s: float) -> None:
        self._t += duration_s
