"""Write files so that a crash never leaves half of one: temporary name, flush, rename.

The new file keeps the permissions of the file it replaces (a file made new gets the usual
ones, 0666 less the umask). A path that is a symbolic link or a special file (a FIFO, a
device) is never replaced: microcal writes only regular files (see :mod:`.safe_open`).
"""

from __future__ import annotations

import os
import stat
import tempfile
from collections.abc import Callable
from pathlib import Path

from ..errors import FormatError
from .safe_open import check_replaceable

__all__ = ["write_atomic", "write_text_atomic"]


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


_UMASK = _umask()  # read once: os.umask sets it, which is not safe while threads write


def write_atomic(path: str | os.PathLike[str], write: Callable[[Path], None]) -> Path:
    """Call ``write(tmp_path)`` to fill a temporary file beside ``path``, then rename it.

    The temporary file is removed if ``write`` fails; ``path`` is either the old file or the
    complete new one, never a mixture.

    The new file has the mode of the file it replaces, or ``0666`` less the umask.

    Raises
    ------
    FormatError
        The file cannot be written (no permission, disk full, a folder of that name), or
        ``path`` is a symbolic link or a special file (nothing is written).
    """
    target = Path(path)
    check_replaceable(target)
    try:
        target.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp_name = tempfile.mkstemp(prefix=f".{target.name}.", suffix=".tmp", dir=target.parent)
    except OSError as exc:
        raise FormatError(f"{target}: cannot be written ({exc.strerror or exc})") from None
    os.close(fd)
    tmp = Path(tmp_name)
    try:
        write(tmp)
        with open(tmp, "rb+") as fh:
            os.fsync(fh.fileno())
        os.chmod(tmp, _mode_for(target))  # mkstemp makes 0600
        check_replaceable(target)  # a link put there while the new file was written
        os.replace(tmp, target)
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        raise FormatError(
            f"{target}: cannot be written ({exc.strerror or exc}); nothing was replaced"
        ) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return target


def _mode_for(target: Path) -> int:
    """The permissions of the file ``target`` replaces; the usual ones for a new file."""
    try:
        st = os.lstat(target)
    except OSError:
        return 0o666 & ~_UMASK
    return st.st_mode & 0o777 if stat.S_ISREG(st.st_mode) else 0o666 & ~_UMASK


def write_text_atomic(path: str | os.PathLike[str], text: str) -> Path:
    """Write UTF-8 text atomically."""

    def write(tmp: Path) -> None:
        tmp.write_text(text, encoding="utf-8")

    return write_atomic(path, write)
