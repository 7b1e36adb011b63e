"""Work over a few independent items in forked processes, with progress from inside them.

:func:`fork_map` runs ``fn(item, tick)`` for each item, each in a process forked from this
one (so ``fn`` may be a closure over anything in memory: frames, callables, paths), and
gives the results in the items' order. ``tick(*args)`` called inside ``fn`` reaches the
caller's ``progress(*args)`` in this process (the arguments must pickle). The items run
here, one after the other, with the same results, where forking is not safe (only Linux
forks here: macOS's system libraries are not fork-safe), when one worker is asked for, or
inside a daemonic worker (which may not have children).

Failures end the whole call at once: an exception in a worker is raised here (as a
``RuntimeError`` naming it when it cannot be sent back), a worker that dies without a
result is named, and on any of these, or Ctrl-C here, every worker still running is
ended. Workers leave Ctrl-C to this process.

:class:`Background` computes one thing in a forked process while this one goes on (the demo
calibrates its cameras while it acquires the poses) and gives its result, or raises its
error, when asked; where forking is not safe it computes it here, then.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import os
import pickle
import signal
import sys
import time
import weakref
from collections.abc import Callable, Iterator, Sequence
from multiprocessing import get_all_start_methods, get_context
from typing import Any, Generic, TypeVar

__all__ = ["Background", "can_fork", "fork_map", "ignore_interrupts"]

T = TypeVar("T")
R = TypeVar("R")
Tick = Callable[..., None]

#: How often the caller looks for ticks and results, s.
POLL_S = 0.02


def can_fork() -> bool:
    """Whether processes may be forked here: Linux (macOS offers fork, but its system
    libraries, and OpenCV on them, are not safe across it)."""
    return sys.platform.startswith("linux") and "fork" in get_all_start_methods()


def ignore_interrupts() -> None:
    """A worker's start: Ctrl-C, sent to the whole process group, is the caller's to act on."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)


def _nothing(*_: Any) -> None:
    pass


def _child(
    fn: Callable[[Any, Tick], Any], item: Any, conn: Any, ticks: Any, reader: Any = None
) -> None:
    """A worker: ``fn(item)``, its result or its exception sent back through ``conn``.

    ``reader``, the caller's end of ``conn``, is closed here first: should the caller end
    without reading, a result too large for the pipe then fails to send instead of waiting
    for a reader that never comes."""
    if reader is not None:
        reader.close()
    ignore_interrupts()
    try:
        message: tuple[str, Any] = ("ok", fn(item, lambda *args: ticks.put(args)))
    except BaseException as exc:  # everything goes back to the caller, which decides
        message = ("error", _portable(exc))
    try:
        conn.send(message)
    except (BrokenPipeError, ConnectionResetError):  # the caller has ended: nobody to tell
        return
    except Exception as exc:  # a result that does not pickle
        conn.send(("error", RuntimeError(f"the result does not pickle: {exc}")))
    conn.close()


def _portable(exc: BaseException) -> BaseException:
    """The exception itself if it survives pickling, else a RuntimeError naming it."""
    try:
        pickle.loads(pickle.dumps(exc))
    except Exception:
        return RuntimeError(f"{type(exc).__name__}: {exc}")
    return exc


def _receive(conn: Any) -> tuple[str, Any] | None:
    """A worker's message, or None when it ended without one."""
    try:
        if conn.poll():
            message: tuple[str, Any] = conn.recv()
            return message
    except (EOFError, OSError):
        pass
    return None


def fork_map(
    fn: Callable[[T, Tick], R],
    items: Sequence[T],
    workers: int | None,
    progress: Tick | None = None,
) -> list[R]:
    """``[fn(item, tick) for item in items]``, in up to ``workers`` forked processes.

    Parameters
    ----------
    fn : callable (item, tick) -> result
        The work on one item; it calls ``tick()`` (or ``tick(*args)``) as it progresses. Its
        result must pickle.
    items : sequence
    workers : int or None
        Processes at once (None: one per core; 1, or where forking is not safe: all here,
        in order).
    progress : callable (*args) -> None, optional
        Called here once per ``tick(*args)`` of any worker, with its arguments.

    Raises
    ------
    RuntimeError
        A worker died without a result (killed, or crashed in a library).
    """
    tick = progress or _nothing
    workers = min(workers or os.cpu_count() or 1, len(items))
    if workers <= 1 or not can_fork() or multiprocessing.current_process().daemon:
        return [fn(item, tick) for item in items]
    ctx = get_context("fork")
    ticks = ctx.SimpleQueue()
    results: dict[int, Any] = {}
    running: dict[int, tuple[Any, Any]] = {}  # index -> (process, connection)
    todo = list(range(len(items)))

    def drain() -> None:
        while not ticks.empty():
            tick(*ticks.get())

    try:
        while todo or running:
            while todo and len(running) < workers:
                k = todo.pop(0)
                here, there = ctx.Pipe(duplex=False)
                proc = ctx.Process(target=_child, args=(fn, items[k], there, ticks, here),
                                   daemon=True)  # fmt: skip
                proc.start()
                there.close()
                running[k] = (proc, here)
            time.sleep(POLL_S)
            drain()
            for k, (proc, conn) in list(running.items()):
                if not conn.poll() and proc.is_alive():
                    continue
                message = _receive(conn)
                proc.join()
                del running[k]
                if message is None:
                    raise RuntimeError(
                        f"a worker process ended without a result (exit code {proc.exitcode}): "
                        "killed, or crashed in a library; run again, or with one worker"
                    )
                status, value = message
                if status == "error":
                    raise value
                results[k] = value
        drain()
    finally:
        for proc, _ in running.values():
            proc.terminate()
        for proc, _ in running.values():
            proc.join()
    return [results[k] for k in range(len(items))]


class _NoTicks:
    """The progress queue of :func:`_child`, unused by :class:`Background`."""

    def put(self, _: object) -> None:
        pass


class Background(Generic[R]):
    """``fn()`` computed in a forked process from now on; :meth:`result` waits for it.

    The child is forked (it sees everything in memory, closures included) and sends its
    result back when asked for it; where forking is not safe (:func:`can_fork`) ``fn`` runs
    here, when its result is asked for. Either way the result is the same.

    Parameters
    ----------
    fn : callable () -> result
        Its result must pickle; an exception it raises is raised by :meth:`result`.
    """

    def __init__(self, fn: Callable[[], R]) -> None:
        self._fn = fn
        self._proc: Any = None
        self._conn: Any = None
        if can_fork() and not multiprocessing.current_process().daemon:
            ctx = get_context("fork")
            here, there = ctx.Pipe(duplex=False)
            self._proc = ctx.Process(
                target=_child, args=(lambda _item, _tick: fn(), None, there, _NoTicks(), here),
                daemon=True,
            )  # fmt: skip
            self._proc.start()
            there.close()
            self._conn = here
            # a result never asked for (an error in between): the process ends with this
            self._finalizer = weakref.finalize(self, _end, self._proc, here)

    def done(self) -> bool:
        """Whether :meth:`result` would return at once (the forked computation has sent its
        result or ended; not forked: always)."""
        if self._proc is None:
            return True
        return bool(self._conn.poll()) or not self._proc.is_alive()

    def result(self) -> R:
        """The result (computed here if it was not forked). Ask for it once: a second call
        computes it again, here.

        Raises
        ------
        RuntimeError
            The process ended without a result (killed, or crashed in a library).
        """
        if self._proc is None:
            return self._fn()
        try:
            message = self._conn.recv()
        except (EOFError, OSError):
            message = None
        finally:
            self._proc.join()
            self._conn.close()
            self._proc = None
        if message is None:
            raise RuntimeError(
                "a background process ended without a result: killed, or crashed in a library"
            )
        status, value = message
        if status == "error":
            raise value
        out: R = value
        return out

    def cancel(self) -> None:
        """End the process if it still runs (its result is no longer wanted)."""
        if self._proc is not None:
            _end(self._proc, self._conn)
            self._proc = None


def parent_messages(conn: Any) -> Iterator[Any]:
    """In a forked helper process: what its parent sends through ``conn``, in order, until the
    parent closes the pipe or has ended without a word (looked at every second)."""
    parent = os.getppid()
    while True:
        try:
            while not conn.poll(1.0):
                if os.getppid() != parent:
                    return
            message = conn.recv()
        except (EOFError, OSError):
            return
        yield message


def end_helper(proc: Any, conn: Any, goodbye: Any) -> None:
    """Send a forked helper ``goodbye``, give it a second to end, terminate it if it has not,
    and close the connection."""
    with contextlib.suppress(OSError, ValueError):
        conn.send(goodbye)
    proc.join(timeout=1.0)
    if proc.is_alive():
        proc.terminate()
        proc.join()
    conn.close()


def _end(proc: Any, conn: Any) -> None:
    """Terminate a background process (if it still runs) and close its connection."""
    if proc.is_alive():
        proc.terminate()
    proc.join()
    conn.close()
