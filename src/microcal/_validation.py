"""Shape and value checks used at every public entry point.

They turn array-like input into float64 arrays and raise :class:`~microcal.errors.InputError`
with a message naming the argument, the expected shape and the shape that was given.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .errors import InputError

__all__ = ["FloatArray", "as_array", "as_rows"]

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
