"""Simulated frames painted on another core while the run goes on.

A simulated camera's grab plans the frame (where each target is, at the grab's time), draws
the frame's noise and returns; painting the targets (:func:`~microcal.sim.camera.paint`, most
of a grab's time) is a pure function of the plan, so it may run in another process. A
:class:`PaintProcess` is a forked process that paints the jobs it is sent, in order, and
gives each frame its reflectance when the frame is first read. The frames are the same, bit
for bit, as painting each at its grab gives: the plan and the noise are drawn here, in the
same order, and the painting draws nothing.

Use it around a run whose grabs come faster than they are read (the settle loop sends each
frame to its search one grab later, :mod:`microcal.procedures.settle_search`)::

    with painting_elsewhere(platform.cameras.values()):
        acquire(...)

Where forking is not safe (:func:`microcal._parallel.can_fork`), or inside a daemonic
worker, the cameras paint at the grab as usual.
"""

from __future__ import annotations

import contextlib
import multiprocessing
import threading
import weakref
from collections import deque
from collections.abc import Iterable, Iterator
from multiprocessing import get_context
from typing import Any

import numpy as np
from numpy.typing import NDArray

from .._parallel import can_fork, end_helper, ignore_interrupts, parent_messages
from .camera import Box, Painted, PaintJob, SimCamera, paint, paint_here

__all__ = ["PaintProcess", "painting_elsewhere"]

Result = tuple[Box | None, NDArray[np.float32] | None]
#: Frames sent ahead of the oldest one not yet answered, at most.
MAX_AHEAD = 4


def _serve(conn: Any, other: Any) -> None:
    """The forked process: jobs in, painted boxes out, in order (``other``: the run's end
    of the pipe, closed here)."""
    other.close()
    ignore_interrupts()
    for message in parent_messages(conn):
        if message is None:
            return
        try:
            conn.send(("painted", paint(message)))
        except Exception as exc:  # sent back, raised where the frame is read
            conn.send(("error", f"{type(exc).__name__}: {exc}"))


class _Pending:
    """One frame's painting, answered in the order the jobs were sent."""

    def __init__(self, owner: PaintProcess) -> None:
        self._owner = owner
        self.result: Result | None = None
        self.error = ""

    def __call__(self) -> Result:
        self._owner._wait_for(self)
        if self.error:
            raise RuntimeError(f"painting a simulated frame failed: {self.error}")
        assert self.result is not None
        return self.result


class PaintProcess:
    """A forked process painting simulated frames (see the module docstring); a painter for
    :attr:`SimCamera.painter <microcal.sim.camera.SimCamera.painter>`.

    ``forked`` is False where forking is not safe: then each job is painted at once, here.
    Frames may be read from any thread (their answers are read under a lock, in order).
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._waiting: deque[_Pending] = deque()
        self._proc: Any = None
        self._conn: Any = None
        if can_fork() and not multiprocessing.current_process().daemon:
            ctx = get_context("fork")
            here, there = ctx.Pipe(duplex=True)
            self._proc = ctx.Process(target=_serve, args=(there, here), daemon=True)
            self._proc.start()
            there.close()
            self._conn = here
            self._finalizer = weakref.finalize(self, end_helper, self._proc, here, None)

    @property
    def forked(self) -> bool:
        return self._proc is not None

    def __call__(self, job: PaintJob) -> Painted:
        if self._proc is None:
            return paint_here(job)
        with self._lock:
            oldest = self._waiting[0] if len(self._waiting) >= MAX_AHEAD else None
        if oldest is not None:  # bounded: neither end's pipe fills while the other waits
            self._wait_for(oldest)
        pending = _Pending(self)
        with self._lock:
            self._conn.send(job)
            self._waiting.append(pending)
        return pending

    def _wait_for(self, pending: _Pending) -> None:
        with self._lock:
            while pending.result is None and not pending.error:
                if self._proc is None:
                    pending.error = "the painting process was closed before the frame was read"
                    break
                kind, value = self._conn.recv()
                first = self._waiting.popleft()
                if kind == "painted":
                    first.result = value
                else:
                    first.error = value

    def close(self) -> None:
        """Read what is still being painted, then end the process."""
        if self._proc is None:
            return
        with self._lock:
            waiting = list(self._waiting)
        for pending in waiting:
            with contextlib.suppress(RuntimeError, EOFError, OSError):
                self._wait_for(pending)
        with self._lock:
            end_helper(self._proc, self._conn, None)
            self._proc = None


@contextlib.contextmanager
def painting_elsewhere(cameras: Iterable[object]) -> Iterator[PaintProcess]:
    """Let the simulated cameras among ``cameras`` paint in one forked process while the block
    runs; afterwards they paint at the grab again (frames grabbed inside stay readable)."""
    sims = [c for c in cameras if isinstance(c, SimCamera)]
    process = PaintProcess()
    for camera in sims:
        camera.painter = process
    try:
        yield process
    finally:
        for camera in sims:
            camera.painter = paint_here
        process.close()
