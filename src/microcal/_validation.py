"""Shape and value checks used at every public entry point.

They turn array-like input into float64 arrays and raise :class:`~microcal.errors.InputError`
with a message naming the argument, the expected shape and the shape that was given.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError

__all__ = [
    "EXCERPT_CHARS",
    "NAME_PATTERN",
    "FloatArray",
    "as_array",
    "as_rows",
    "check_number",
    "did_you_mean",
    "excerpt",
    "name_problem",
]

FloatArray = NDArray[np.float64]


def _shape_text(shape: Sequence[int | None]) -> str:
    inner = ", ".join("N" if s is None else str(s) for s in shape)
    return f"({inner},)" if len(shape) == 1 else f"({inner})"


def _to_float(value: ArrayLike, name: str, shape: Sequence[int | None]) -> FloatArray:
    try:
        return np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(
            f"{name}: expected numbers of shape {_shape_text(shape)}, got {type(value).__name__}"
        ) from None


def _check(arr: FloatArray, name: str, shape: Sequence[int | None], finite: bool) -> FloatArray:
    if arr.ndim != len(shape) or any(
        s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)
    ):
        raise InputError(f"{name}: expected shape {_shape_text(shape)}, got {arr.shape}")
    if finite and not np.all(np.isfinite(arr)):
        bad = int(np.count_nonzero(~np.isfinite(arr)))
        raise InputError(f"{name}: expected finite values, got {bad} NaN or infinite value(s)")
    return arr


def as_array(
    value: ArrayLike, name: str, shape: Sequence[int | None], *, finite: bool = True
) -> FloatArray:
    """Convert ``value`` to a float64 array of the given shape.

    Parameters
    ----------
    value : array_like
        The input.
    name : str
        The argument's name, used in the error message.
    shape : sequence of int or None
        The expected shape; ``None`` matches any length.
    finite : bool
        Reject NaN and infinities.

    Raises
    ------
    InputError
        If the shape differs, the values are not numbers, or (with ``finite``) some are not finite.
    """
    return _check(_to_float(value, name, shape), name, shape, finite)


def as_rows(value: ArrayLike, name: str, width: int, *, finite: bool = True) -> FloatArray:
    """Points as rows: accept ``(N, width)`` or one point ``(width,)``; return ``(N, width)``."""
    shape = (None, width)
    arr = _to_float(value, name, shape)
    if arr.ndim == 1 and arr.shape[0] == width:
        arr = arr[None, :]
    return _check(arr, name, shape, finite)


def check_limits(
    d_um: ArrayLike,
    limits_um: ArrayLike,
    *,
    axes: Sequence[str] = ("x", "y", "z"),
    row: str = "command",
    owner: str = "",
    targets_um: ArrayLike | None = None,
) -> FloatArray:
    """Refuse joint values outside the soft limits: the one limit check of microcal.

    Parameters
    ----------
    d_um : (N, k) or (k,) float
        Joint values, µm; non-finite values count as outside.
    limits_um : (k, 2) float
        Soft limits (low, high) per joint.
    axes : sequence of k str
        The joints' names, for the message.
    row : str
        What a row is ("command", "target"), for the message.
    owner : str
        The device refusing, for the message.
    targets_um : (N, 3) float, optional
        The positions the rows were computed for, named in the message.

    Returns
    -------
    d_um : the values as a float array of the same shape.

    Raises
    ------
    LimitError
        Naming the first value outside, its limits and how many rows are outside.
    """
    from .errors import LimitError

    d = np.asarray(d_um, dtype=np.float64)
    rows = np.atleast_2d(d)
    lim = as_array(limits_um, "limits_um", (rows.shape[1], 2))
    outside = (rows < lim[:, 0]) | (rows > lim[:, 1]) | ~np.isfinite(rows)
    bad = np.flatnonzero(outside.any(axis=1))
    if bad.size:
        i = int(bad[0])
        k = int(np.flatnonzero(outside[i])[0])
        who = f"{owner}: " if owner else ""
        which = f"{row} {i + 1}: " if d.ndim == 2 else ""
        target = ""
        if targets_um is not None:
            target = f" for target {np.round(np.atleast_2d(targets_um)[i], 3).tolist()} µm"
        count = f" ({bad.size} of {rows.shape[0]} {row}s outside)" if bad.size > 1 else ""
        raise LimitError(
            f"{who}{which}axis {axes[k]} = {rows[i, k]:.3f} µm{target} is outside the soft "
            f"limits [{lim[k, 0]:g}, {lim[k, 1]:g}] µm{count}; nothing was moved"
        )
    return d


def check_number(
    name: str,
    value: object,
    low: float | None = None,
    high: float | None = None,
    *,
    above: float | None = None,
    integer: bool = False,
) -> float:
    """A finite number within its range, or an InputError saying expected vs got.

    Parameters
    ----------
    low, high : float, optional
        Inclusive bounds.
    above : float, optional
        An exclusive lower bound (``above=0``: strictly positive).
    integer : bool
        Only whole numbers (bool is never a number here).

    Returns
    -------
    float
        ``value`` as a float.
    """
    kinds = (int, np.integer) if integer else (int, float, np.integer, np.floating)
    v = math.nan
    if isinstance(value, kinds) and not isinstance(value, bool):
        try:
            v = float(value)
        except OverflowError:  # an integer beyond any float
            v = math.inf
    if not math.isfinite(v):
        what = "an integer" if integer else "a finite number"
        shown = repr(value) if len(repr(value)) < 40 else f"{repr(value)[:30]}..."
        raise InputError(f"{name}: expected {what}, got {shown}")
    bounds = []
    if above is not None:
        bounds.append(f"> {above:g}")
    if low is not None:
        bounds.append(f">= {low:g}")
    if high is not None:
        bounds.append(f"<= {high:g}")
    if (
        (above is not None and not v > above)
        or (low is not None and v < low)
        or (high is not None and v > high)
    ):
        raise InputError(f"{name}: expected a number {' and '.join(bounds)}, got {value!r}")
    return v


def did_you_mean(value: object, choices: Sequence[str], *, quote: bool = True) -> str:
    """``"did you mean 'seed'? "`` for the choice nearest a misspelt ``value``, else ``""``."""
    import difflib

    near = difflib.get_close_matches(str(value), list(choices), n=1)
    if not near:
        return ""
    return f"did you mean {near[0]!r}? " if quote else f"did you mean {near[0]}? "


#: What the name of a camera or a device may be: it becomes part of file names
#: (``images/top_0001.tiff``) and of pages, so it is a plain word (no ``/``, no ``..``).
NAME_PATTERN = re.compile(r"[A-Za-z0-9][A-Za-z0-9_.-]{0,63}")


#: Most characters of a file's text a message quotes.
EXCERPT_CHARS = 40


def excerpt(value: object, limit: int = EXCERPT_CHARS) -> str:
    """A short, escaped quotation of ``value`` (from a file) for a one-line message.

    ``value`` as Python writes it (a string quoted: ``'abc'``) with every control and
    non-ASCII character escaped, and at most ``limit`` characters of a string (``...`` marks
    a cut): the file may be anything (another program's data, a secret a link points to),
    and the message lands in terminals and logs.
    """
    if not isinstance(value, str):
        shown = ascii(value)
        return shown if len(shown) <= limit else shown[:limit] + "..."
    quoted = ascii(value[:limit])
    return quoted + "..." if len(value) > limit else quoted


def name_problem(name: object) -> str | None:
    """Why ``name`` cannot be a camera's or a device's name, or None when it can.

    A name is 1 to 64 letters, digits, ``_``, ``.`` and ``-``, beginning with a letter or
    a digit, without ``..`` (:data:`NAME_PATTERN`).
    """
    if isinstance(name, str) and NAME_PATTERN.fullmatch(name) and ".." not in name:
        return None
    return (
        f"{excerpt(name)} is not a name (expected 1 to 64 letters, digits, '_', '.' or '-', "
        "beginning with a letter or digit, without '..')"
    )
