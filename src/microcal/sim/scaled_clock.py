"""A clock whose simulated seconds follow the wall clock, ``time_scale`` times faster (the
digital twin's, :mod:`microcal.sim.twin`)."""

from __future__ import annotations

import math
import time

from ..devices.base import Clock
from ..errors import InputError

__all__ = ["ScaledClock"]


class ScaledClock(Clock):
    """Simulated seconds that follow the wall clock, ``time_scale`` times faster.

    ``now_s() = (time.monotonic() - t0) * time_scale`` with ``t0`` the moment of
    construction; ``sleep(d)`` waits ``d / time_scale`` wall seconds.

    Parameters
    ----------
    time_scale : float
        Simulated seconds per wall second (> 0; 1 is real time).

    Raises
    ------
    InputError
        A time scale that is not a finite number > 0.
    """

    def __init__(self, time_scale: float = 1.0) -> None:
        self.time_scale = _time_scale(time_scale)
        self._t0 = time.monotonic()

    def now_s(self) -> float:
        return (time.monotonic() - self._t0) * self.time_scale

    def _sleep(self, duration_s: float) -> None:
        if duration_s > 0:
            time.sleep(duration_s / self.time_scale)


def _time_scale(value: object) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]  # anything else is refused below
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, bool) or not (math.isfinite(v) and v > 0):
        raise InputError(f"time_scale: expected a finite number > 0, got {value!r}")
    return v
