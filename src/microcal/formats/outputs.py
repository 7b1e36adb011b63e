"""Outputs checked before any work: writable, and never a file that is not ours to replace.

Every writer of microcal replaces only a file of its own kind that microcal wrote (a
calibration.json by a calibration.json, never a cameras.json, a CSV or a user's notes), and
says so before it starts, not after an hour of acquisition or a fit.
"""

from __future__ import annotations

import os
import stat
from collections.abc import Callable
from pathlib import Path

from ..errors import InputError
from .safe_open import kind_of, opened_regular

__all__ = [
    "check_not_special",
    "check_output",
    "check_writable",
    "foreign_mat",
    "foreign_report",
    "foreign_twin_rig",
]


def check_output(
    path: str | os.PathLike[str],
    *,
    kind: str,
    foreign: Callable[[Path], str | None],
    example: str,
    option: str = "--out",
) -> Path:
    """Refuse an output that is a directory, a file that is not ours (``foreign`` says what it
    holds), or a place without write permission; returns the path.

    Parameters
    ----------
    kind : str
        What the output is, for the message (``a report``).
    foreign : callable (path) -> str or None
        For an existing file: None when microcal wrote it and it is of this kind, else what
        it holds (``a microcal.cameras/1 file``).
    example : str
        A file name to suggest.

    Raises
    ------
    InputError
        ``OPTION PATH: is a directory`` / ``holds WHAT, not KIND`` / ``cannot write in DIR``,
        each with the fix; ``is a FIFO (a device, a symbolic link), not a regular file``:
        microcal writes only a regular file or a new path (:mod:`.safe_open`).
    """
    p = Path(path)
    check_not_special(p, option, example)
    if p.is_dir():
        raise InputError(f"{option} {p}: is a directory; give a file name such as {example}")
    held = foreign(p) if p.exists() else None
    if held is not None:
        raise InputError(
            f"{option} {p}: holds {held}, not {kind}; microcal replaces only files of that "
            f"kind it wrote: choose another name such as {example}"
        )
    check_writable(p.parent if str(p.parent) else Path("."), f"{option} {p}")
    return p


def check_not_special(path: Path, option: str, example: str) -> None:
    """Refuse an output path that is a symbolic link, a FIFO, a device or a socket.

    It is refused before anything reads it: a FIFO would wait for ever, ``/dev/zero`` would be
    read without end, and a link would have microcal replace what it points to.
    """
    try:
        st_mode = os.lstat(path).st_mode
    except OSError:
        return
    if stat.S_ISREG(st_mode) or stat.S_ISDIR(st_mode):
        return
    raise InputError(
        f"{option} {path}: is {kind_of(st_mode)}, not a regular file; microcal writes only a "
        f"regular file or a new path: give a file name such as {example}"
    )


def check_writable(folder: Path, what: str) -> None:
    """Refuse a folder (or its nearest existing parent) without write permission."""
    parent = folder
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if parent.exists() and not parent.is_dir():
        raise InputError(f"{what}: {parent} is a file, not a folder; choose another place")
    if not os.access(parent, os.W_OK):
        raise InputError(f"{what}: cannot write in {parent} (no permission); choose another place")


def _head(path: Path, n: int) -> bytes:
    try:
        with opened_regular(path) as fh:
            return fh.read(n)
    except (OSError, ValueError):  # ValueError: FormatError, not a regular file
        return b""


_NOT_OURS = "a file microcal did not write"


def foreign_report(path: Path) -> str | None:
    """None for an HTML report microcal wrote (its generator tag)."""
    return None if b'<meta name="generator" content="microcal' in _head(path, 4096) else _NOT_OURS


def foreign_twin_rig(path: Path) -> str | None:
    """None for a rig file ``microcal twin --rig-out`` wrote (its first line)."""
    from .twin_rig_file import RIG_HEADER

    return None if _head(path, 256).startswith(RIG_HEADER.encode("utf-8")) else _NOT_OURS


def foreign_mat(path: Path) -> str | None:
    """None for a MATLAB file ``export_mat`` wrote: MAT 5, every variable a model's struct."""
    if not _head(path, 19).startswith(b"MATLAB 5.0 MAT-file"):
        return _NOT_OURS
    import scipy.io

    try:
        with opened_regular(path) as fh:
            data = scipy.io.loadmat(fh, squeeze_me=True, struct_as_record=False)
    except Exception:
        return "a MATLAB file microcal cannot read"
    models = [v for k, v in data.items() if not k.startswith("__")]
    ours = bool(models) and all(hasattr(m, "kind") and hasattr(m, "coefficients") for m in models)
    return None if ours else "a MATLAB file of other data"
