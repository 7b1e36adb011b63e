"""Opening a file microcal reads or writes: a regular file, never a link's or a device's.

Run directories, calibrations and images come from other labs and from downloads. A file
in them that is a symbolic link could make microcal read (and quote) a file elsewhere, or
truncate, append to or replace one; a FIFO or a device (``/dev/zero``) would make it wait
or read for ever. Every reader and writer of :mod:`microcal.formats` opens through
:func:`open_regular`, which

- does not follow a symbolic link (``O_NOFOLLOW``) unless told that the user named the
  path (``link_ok``);
- opens without blocking (``O_NONBLOCK``, so a FIFO does not wait for a writer), checks with
  ``fstat`` that what it opened is a regular file, then clears the non-blocking flag;
- refuses anything else in one line: ``PATH: is a FIFO, not a regular file; ...``.

The rule for links: a path the user typed (``microcal fit calibration-link.json``, the
``--cameras``, ``--calibration``, ``--rig`` and ``--design`` files, a path given to
:func:`microcal.load_calibration`) may be a symbolic link to a regular file, as any Unix
tool allows. A file a run directory or a record names inside itself (run.json, the journal,
images, commands.csv, the report's inputs), and every file microcal writes, replaces or
appends to (``--out`` files, locks, journal, history of checks), may not be a link.

A directory is left to the caller (``IsADirectoryError``, as ``open`` raises it), so each
reader keeps its own words for that mistake.
"""

from __future__ import annotations

import contextlib
import errno
import os
import stat
from collections.abc import Iterator
from pathlib import Path
from typing import BinaryIO

from ..errors import FormatError

__all__ = [
    "check_replaceable",
    "kind_of",
    "not_regular",
    "open_regular",
    "opened_regular",
    "read_regular_bytes",
    "read_regular_text",
]

_NOFOLLOW = getattr(os, "O_NOFOLLOW", 0)
_NONBLOCK = getattr(os, "O_NONBLOCK", 0)
_CLOEXEC = getattr(os, "O_CLOEXEC", 0)
_BINARY = getattr(os, "O_BINARY", 0)


def kind_of(mode: int) -> str:
    """What a file of ``st_mode`` is, in words (``a FIFO``, ``a device``, ``a symbolic link``)."""
    if stat.S_ISLNK(mode):
        return "a symbolic link"
    if stat.S_ISFIFO(mode):
        return "a FIFO"
    if stat.S_ISCHR(mode) or stat.S_ISBLK(mode):
        return "a device"
    if stat.S_ISSOCK(mode):
        return "a socket"
    if stat.S_ISDIR(mode):
        return "a directory"
    return "not a regular file"


def not_regular(path: str | os.PathLike[str], what: str) -> FormatError:
    """The one-line refusal of ``path``, which is ``what`` (``a FIFO``) instead of a file."""
    return FormatError(
        f"{path}: is {what}, not a regular file; it must be a regular file (put the file "
        f"itself there)"
    )


def open_regular(
    path: str | os.PathLike[str],
    flags: int = os.O_RDONLY,
    mode: int = 0o666,
    *,
    link_ok: bool = False,
) -> int:
    """Open ``path`` (``os.open`` flags) as a regular file; its descriptor (blocking).

    Parameters
    ----------
    flags : int
        ``os.O_RDONLY``, ``os.O_RDWR | os.O_CREAT``, ``os.O_WRONLY | os.O_APPEND`` ...
    mode : int
        The permissions of a file ``os.O_CREAT`` makes (the umask applies).
    link_ok : bool
        The user named this path: a symbolic link to a regular file is followed.

    Raises
    ------
    FormatError
        A symbolic link (unless ``link_ok``), a FIFO, a device or a socket.
    OSError
        As ``os.open`` raises it: no such file, no permission, a directory
        (``IsADirectoryError`` also for a directory opened for reading).
    """
    nofollow = 0 if link_ok else _NOFOLLOW
    try:
        fd = os.open(path, flags | nofollow | _NONBLOCK | _CLOEXEC | _BINARY, mode)
    except OSError as exc:
        if exc.errno == errno.ELOOP and nofollow and os.path.islink(path):
            raise not_regular(path, "a symbolic link") from None
        if exc.errno in (errno.ENXIO, errno.EOPNOTSUPP, errno.ENODEV):
            raise not_regular(path, _kind_at(path)) from None
        raise
    try:
        st_mode = os.fstat(fd).st_mode
        if stat.S_ISDIR(st_mode):
            raise IsADirectoryError(errno.EISDIR, os.strerror(errno.EISDIR), os.fspath(path))
        if not stat.S_ISREG(st_mode):
            raise not_regular(path, kind_of(st_mode))
        if _NONBLOCK:
            os.set_blocking(fd, True)
    except BaseException:
        os.close(fd)
        raise
    return fd


def _kind_at(path: str | os.PathLike[str]) -> str:
    try:
        return kind_of(os.lstat(path).st_mode)
    except OSError:
        return "not a regular file"


@contextlib.contextmanager
def opened_regular(path: str | os.PathLike[str], *, link_ok: bool = False) -> Iterator[BinaryIO]:
    """``path`` opened for reading in binary, as :func:`open_regular` opens it."""
    fd = open_regular(path, link_ok=link_ok)
    with os.fdopen(fd, "rb") as fh:
        yield fh


def read_regular_bytes(path: str | os.PathLike[str], *, link_ok: bool = False) -> bytes:
    """The bytes of a regular file (see :func:`open_regular` for what is refused)."""
    with opened_regular(path, link_ok=link_ok) as fh:
        return fh.read()


def read_regular_text(path: str | os.PathLike[str], *, link_ok: bool = False) -> str:
    """The UTF-8 text of a regular file (``UnicodeDecodeError`` when it is not UTF-8)."""
    return read_regular_bytes(path, link_ok=link_ok).decode("utf-8")


def check_replaceable(path: str | os.PathLike[str]) -> None:
    """Refuse a path microcal would write that is a symbolic link or a special file.

    A missing path, a regular file and a directory pass (a directory is each writer's own
    refusal, with its own words).
    """
    try:
        st_mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    except OSError:
        return  # no permission to look: the write itself says so
    if stat.S_ISREG(st_mode) or stat.S_ISDIR(st_mode):
        return
    raise not_regular(Path(path), kind_of(st_mode))
