"""Wall-clock time per stage of a long run (the demo's time table).

A :class:`StageClock` adds up the wall seconds spent inside each named stage; a stage may be
entered several times (its times add). The demo prints the table at its end and stores it in
results.json (``timing.stages_s``), so that a slower stage is visible from one run to the
next.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager

__all__ = ["StageClock"]


class StageClock:
    """Wall seconds per named stage, in the order the stages were first entered.

    Parameters
    ----------
    clock : callable () -> float, optional
        Seconds (``time.perf_counter`` by default).
    """

    def __init__(self, clock: Callable[[], float] = time.perf_counter) -> None:
        self._clock = clock
        self.stages_s: dict[str, float] = {}

    @contextmanager
    def stage(self, name: str) -> Iterator[None]:
        """Time the block as (part of) stage ``name``."""
        start = self._clock()
        try:
            yield
        finally:
            self.add(name, self._clock() - start)

    def add(self, name: str, seconds: float) -> None:
        """Add ``seconds`` to stage ``name``."""
        self.stages_s[name] = self.stages_s.get(name, 0.0) + max(0.0, float(seconds))

    @property
    def total_s(self) -> float:
        """The stages' seconds together."""
        return float(sum(self.stages_s.values()))
