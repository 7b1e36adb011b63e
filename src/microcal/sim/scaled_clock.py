"""A clock whose simulated seconds follow the wall clock, ``time_scale`` times faster (the
digital twin's, :mod:`microcal.sim.twin`)."""

from __future__ import annotations

import contextlib
import math
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass

from ..devices.base import Clock
from ..errors import InputError

__all__ = ["DeferredWait", "ScaledClock"]


@dataclass
class DeferredWait:
    """The waits a thread deferred (:meth:`ScaledClock.deferred_waits`).

    Attributes
    ----------
    sim_s : float
        Their total, simulated seconds.
    wall_s : float
        Their total, wall seconds (``sim_s / time_scale``).
    """

    sim_s: float = 0.0
    wall_s: float = 0.0


class ScaledClock(Clock):
    """Simulated seconds that follow the wall clock, ``time_scale`` times faster.

    ``now_s() = (time.monotonic() - t0) * time_scale`` with ``t0`` the moment of
    construction; ``sleep(d)`` waits ``d / time_scale`` wall seconds, except on a thread
    within :meth:`deferred_waits`, where it only adds to what that thread owes.

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
        self._deferring = threading.local()

    def now_s(self) -> float:
        return (time.monotonic() - self._t0) * self.time_scale

    @contextlib.contextmanager
    def deferred_waits(self) -> Iterator[DeferredWait]:
        """Within the block, the calling thread's sleeps return at once and add up in the
        :class:`DeferredWait` it yields; the caller waits them out afterwards (the twin's frame
        server renders a frame under the platform's lock and waits out its exposure after
        releasing it). Other threads' sleeps wait as usual."""
        owed = DeferredWait()
        outer = getattr(self._deferring, "owed", None)
        self._deferring.owed = owed
        try:
            yield owed
        finally:
            self._deferring.owed = outer

    def _sleep(self, duration_s: float) -> None:
        owed: DeferredWait | None = getattr(self._deferring, "owed", None)
        if owed is not None:
            owed.sim_s += duration_s
            owed.wall_s = owed.sim_s / self.time_scale
        elif duration_s > 0:
            time.sleep(duration_s / self.time_scale)


def _time_scale(value: object) -> float:
    try:
        v = float(value)  # type: ignore[arg-type]  # anything else is refused below
    except (TypeError, ValueError):
        v = math.nan
    if isinstance(value, bool) or not (math.isfinite(v) and v > 0):
        raise InputError(f"time_scale: expected a finite number > 0, got {value!r}")
    return v
