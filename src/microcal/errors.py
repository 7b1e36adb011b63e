"""The exception hierarchy of microcal.

Every error microcal raises on purpose derives from :class:`MicrocalError`, so a caller can
catch them all at once; each also derives from the built-in exception a Python user would
expect (``ValueError`` for bad input, ``RuntimeError`` for device trouble). Messages say
what was expected, what was found, and what to do about it, in one line.
"""

from __future__ import annotations

__all__ = [
    "DegenerateDataError",
    "DetectionError",
    "DeviceError",
    "DeviceTimeoutError",
    "FormatError",
    "FrameError",
    "InputError",
    "LimitError",
    "MicrocalError",
    "MoveError",
]


class MicrocalError(Exception):
    """Base class of every error microcal raises on purpose."""


class InputError(MicrocalError, ValueError):
    """An argument has the wrong shape, type or value (for example NaN where numbers are needed)."""


class DegenerateDataError(MicrocalError, ValueError):
    """The data cannot determine the quantity asked for (too few points, coplanar, rank loss)."""


class DetectionError(MicrocalError, ValueError):
    """A target could not be detected where one was required."""


class LimitError(MicrocalError, ValueError):
    """A command would take a device outside its travel limits; nothing was moved."""


class FormatError(MicrocalError, ValueError):
    """A file is malformed, of an unknown format version, or inconsistent with itself."""


class DeviceError(MicrocalError, RuntimeError):
    """A device failed, timed out or reported an error."""


class DeviceTimeoutError(DeviceError):
    """A device did not answer in time (transient: the operation may be retried)."""


class MoveError(DeviceError):
    """A move failed (the controller reported an error, or the positioner did not arrive)."""


class FrameError(DeviceError):
    """A camera delivered no frame, or a broken one (transient: grab again)."""
