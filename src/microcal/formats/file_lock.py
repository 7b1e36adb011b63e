"""One writer at a time of a shared file: read, change and replace it under a lock.

Some files are read, changed and written whole (atomically, :mod:`.atomic`) by commands
that may run at once: calibration.json (``fit`` adds a device), the history of checks
beside it (``check`` adds a line) and results.json (``evaluate`` and the demo merge their
parts). Without a lock, two such writers both read the old file and the one that renames
last drops the other's change. :func:`locked_update` holds an exclusive lock from before
the read to after the rename, so writers take turns and every change lands.

The lock is the operating system's (``flock``) on ``.NAME.lock`` beside the file (beside
the file a symbolic link or a ``./`` in the path leads to, so every name of one file
takes one lock). The lock file holds its holder's PID, which a refusal names; it is removed
when the holder is done. One left by a process that was killed holds no lock (the lock
ends with its process): the next writer takes it over and removes it. A lock file is
never followed through a symbolic link. A writer that waits longer than :data:`WAIT_S`
is refused in one line.

On a system without ``fcntl`` (Windows) the lock is not taken.
"""

from __future__ import annotations

import contextlib
import errno
import os
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from ..errors import FormatError, InputError
from .safe_open import check_replaceable, open_regular

if sys.platform != "win32":
    import fcntl

__all__ = ["WAIT_S", "lock_path", "locked_update"]

#: Longest a writer waits for another to finish with the file, s.
WAIT_S = 10.0
#: How often a waiting writer tries the lock again, s.
POLL_S = 0.02

_BUSY = (errno.EWOULDBLOCK, errno.EAGAIN)


def lock_path(path: str | os.PathLike[str]) -> Path:
    """``DIR/NAME`` -> ``DIR/.NAME.lock``, beside the file ``path`` leads to."""
    target = Path(path).resolve()
    return target.with_name(f".{target.name}.lock")


def _open(lock: Path, target: Path) -> int:
    """The lock file, opened (created if missing) as a regular file, never through a link."""
    try:
        lock.parent.mkdir(parents=True, exist_ok=True)
        return open_regular(lock, os.O_RDWR | os.O_CREAT, 0o666)
    except FormatError:
        if os.path.islink(lock):
            raise InputError(
                f"{lock}: is a symbolic link, where microcal locks {target.name}; remove it"
            ) from None
        raise _not_a_file(lock, target) from None
    except OSError as exc:
        if exc.errno == errno.EISDIR:
            raise _not_a_file(lock, target) from None
        raise FormatError(
            f"{target}: cannot be written (its lock file {lock.name}: {exc.strerror or exc})"
        ) from None


def _not_a_file(lock: Path, target: Path) -> InputError:
    return InputError(f"{lock}: is not a file, where microcal locks {target.name}; remove it")


def _holder(fd: int) -> str:
    try:
        pid = os.pread(fd, 32, 0).decode("ascii").strip()
    except (OSError, UnicodeDecodeError):
        pid = ""
    return f"PID {pid}" if pid.isdigit() else "another process"


def _take(lock: Path, target: Path, wait_s: float) -> int:
    """Lock ``lock`` (waiting up to ``wait_s``); its open descriptor."""
    deadline = time.monotonic() + wait_s
    while True:
        fd = _open(lock, target)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as exc:
            if exc.errno not in _BUSY:
                os.close(fd)
                raise FormatError(
                    f"{target}: cannot be locked for writing ({exc.strerror or exc})"
                ) from None
            if time.monotonic() >= deadline:
                holder = _holder(fd)
                os.close(fd)
                raise InputError(
                    f"{target}: in use by microcal ({holder}) for more than {wait_s:g} s; "
                    f"wait for it to end or stop it, then run again"
                ) from None
            os.close(fd)
            time.sleep(POLL_S)
            continue
        try:
            same = os.fstat(fd).st_ino == os.stat(lock, follow_symlinks=False).st_ino
        except FileNotFoundError:
            same = False
        if same:
            return fd
        os.close(fd)  # locked a file its holder had just removed: take the one there now


@contextlib.contextmanager
def locked_update(path: str | os.PathLike[str], wait_s: float | None = None) -> Iterator[Path]:
    """Hold ``path``'s lock for the block: read the file, change it and write it inside.

    Parameters
    ----------
    path : path
        The file to be read and replaced (it may not exist yet; its folder is made).
    wait_s : float, optional
        Longest wait for another writer, s; :data:`WAIT_S` by default.

    Yields
    ------
    Path
        ``path``.

    Raises
    ------
    InputError
        Another process held the lock for the whole wait: ``FILE: in use by microcal (PID
        N) for more than 10 s; ...``; or the lock file is a symbolic link or not a file.
    FormatError
        The lock file cannot be made (no permission, a read-only folder); ``path`` is a
        symbolic link or a special file (no lock is taken, nothing is written).
    """
    target = Path(path)
    check_replaceable(target)  # before the lock: a link's lock would lie beside its target
    if sys.platform == "win32":  # pragma: no cover
        yield target
        return
    lock = lock_path(target)
    fd = _take(lock, target, WAIT_S if wait_s is None else wait_s)
    try:
        with contextlib.suppress(OSError):  # the PID only names the holder in a refusal
            os.ftruncate(fd, 0)
            os.write(fd, f"{os.getpid()}\n".encode("ascii"))
        yield target
    finally:
        with contextlib.suppress(OSError):
            lock.unlink()
        os.close(fd)
