"""Work over a few independent items in forked processes, with progress from inside them.

:func:`fork_map` runs ``fn(item, tick)`` for each item, each in a process forked from this
one (so ``fn`` may be a closure over anything in memory: frames, callables, open files'
paths), and gives the results in the items' order. ``tick()`` called inside ``fn`` reaches
the caller's ``progress`` in this process. Where the system cannot fork, or one worker is
asked for, the items run here, one after the other, with the same results.

The workers leave Ctrl-C to this process, which ends them (``Pool.terminate``) on leaving:
an interrupted run stops at once, not after every item. An exception in a worker is raised
here.
"""

from __future__ import annotations

import signal
import time
from collections.abc import Callable, Sequence
from multiprocessing import get_all_start_methods, get_context
from typing import Any, TypeVar

__all__ = ["can_fork", "fork_map", "ignore_interrupts"]

T = TypeVar("T")
R = TypeVar("R")
Tick = Callable[[], None]

#: The job of the pool being run: (fn, queue of ticks); forked workers inherit it.
_JOB: tuple[Callable[[Any, Tick], Any], Any] | None = None
#: How often the caller looks for ticks and results, s.
POLL_S = 0.02


def can_fork() -> bool:
    """Whether this system starts processes by forking (Linux; not Windows, nor macOS's
    default)."""
    return "fork" in get_all_start_methods()


def _nothing() -> None:
    pass


def ignore_interrupts() -> None:
    """A worker's start: Ctrl-C, sent to the whole process group, is the caller's to act on."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _run(item: Any) -> Any:
    assert _JOB is not None
    fn, ticks = _JOB
    return fn(item, lambda: ticks.put(1))


def fork_map(
    fn: Callable[[T, Tick], R],
    items: Sequence[T],
    workers: int,
    progress: Tick | None = None,
) -> list[R]:
    """``[fn(item, tick) for item in items]``, in up to ``workers`` forked processes.

    Parameters
    ----------
    fn : callable (item, tick) -> result
        The work on one item; it calls ``tick()`` as it progresses. Its result must pickle.
    items : sequence
    workers : int
        Processes at once (1, or a system that cannot fork: all here, in order).
    progress : callable () -> None, optional
        Called here once per ``tick()`` of any worker.
    """
    global _JOB
    tick = progress or _nothing
    workers = min(workers, len(items))
    if workers <= 1 or not can_fork():
        return [fn(item, tick) for item in items]
    ctx = get_context("fork")
    ticks = ctx.SimpleQueue()
    _JOB = (fn, ticks)
    try:
        with ctx.Pool(workers, initializer=ignore_interrupts) as pool:
            pending = [pool.apply_async(_run, (item,)) for item in items]
            while not all(p.ready() for p in pending):
                time.sleep(POLL_S)
                while not ticks.empty():
                    ticks.get()
                    tick()
            while not ticks.empty():
                ticks.get()
                tick()
            return [p.get() for p in pending]
    finally:
        _JOB = None
