"""One microcal at a time in a run directory: an exclusive lock that names its holder.

``acquire`` (new or resumed) and ``measure`` hold ``RUN_DIR/.microcal.lock`` while they work.
The lock is the operating system's (``flock``), so it ends with its process, even one
killed by SIGKILL: a stale lock file never blocks the next command. The file holds the
holder's PID, which the refusal names.

On a system without ``fcntl`` (Windows) the lock is not taken.
"""

from __future__ import annotations

import contextlib
import os
import sys
from collections.abc import Iterator
from pathlib import Path

from ..errors import FormatError, InputError
from .safe_open import kind_of, open_regular

if sys.platform != "win32":
    import fcntl

__all__ = ["LOCK_NAME", "run_lock"]

LOCK_NAME = ".microcal.lock"


def _holder(fd: int) -> str:
    try:
        pid = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        pid = ""
    return f"PID {pid}" if pid.isdigit() else "another process"


@contextlib.contextmanager
def run_lock(run_dir: str | os.PathLike[str], command: str) -> Iterator[None]:
    """Hold the run directory's lock for the block.

    Parameters
    ----------
    run_dir : path
        An existing directory.
    command : str
        What takes it (``acquire``, ``measure``), for the refusal's words.

    Raises
    ------
    InputError
        Another process holds the lock: ``RUN_DIR: in use by microcal (PID N); wait for it
        or stop it``; the lock file is a symbolic link, a FIFO or a device (never followed).
    """
    path = Path(run_dir) / LOCK_NAME
    if sys.platform == "win32":  # pragma: no cover
        yield
        return
    for _ in range(10):  # bounded: a holder that removes the file between open and lock
        try:
            fd = open_regular(path, os.O_RDWR | os.O_CREAT, 0o644)
        except FormatError:
            what = kind_of(os.lstat(path).st_mode)
            raise InputError(
                f"{path}: is {what}, not a regular file, where microcal locks the run; remove it"
            ) from None
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            holder = _holder(fd)
            os.close(fd)
            raise InputError(
                f"{run_dir}: in use by microcal ({holder}); wait for it to end or "
                f"stop it before {command}"
            ) from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path, follow_symlinks=False).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # locked a file its holder had just removed: take the new one
    else:  # pragma: no cover - ten races in a row
        raise InputError(f"{run_dir}: could not take its lock; try again")
    try:
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode("ascii"))
        yield
    finally:
        with contextlib.suppress(OSError):
            path.unlink()
        os.close(fd)
