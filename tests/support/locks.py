"""A file's lock held by another process, for the tests of one writer at a time."""

from __future__ import annotations

import contextlib
import multiprocessing
from collections.abc import Iterator
from pathlib import Path

from microcal.formats.file_lock import locked_update


@contextlib.contextmanager
def held_elsewhere(path: Path) -> Iterator[int]:
    """Another (forked) process holds ``path``'s lock for the block; yields its PID."""
    ctx = multiprocessing.get_context("fork")
    taken, release = ctx.Event(), ctx.Event()

    def hold() -> None:
        with locked_update(path):
            taken.set()
            release.wait(30)

    proc = ctx.Process(target=hold)
    proc.start()
    try:
        assert taken.wait(10), "the holder did not take the lock"
        assert proc.pid is not None
        yield proc.pid
    finally:
        release.set()
        proc.join(10)
