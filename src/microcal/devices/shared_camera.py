"""A camera shared by two users at once: a live view and a measurement.

:class:`SharedCamera` wraps any :class:`~microcal.devices.base.Camera` so that grabs from two
threads (the station page's live view and the closed loop's vision probe) take turns, one
grab at a time, and keeps the latest frame with the time it was grabbed: the live view shows
the probe's frames while a move measures, instead of asking the camera for more.
"""

from __future__ import annotations

import threading
import time

import numpy as np
from numpy.typing import NDArray

from .base import Camera

__all__ = ["SharedCamera"]


class SharedCamera(Camera):
    """``inner`` behind a lock, with its latest frame (see the module docstring).

    Parameters
    ----------
    inner : Camera
        The camera; closing this one closes it.
    """

    def __init__(self, inner: Camera) -> None:
        super().__init__(
            inner.name, inner.sensor_size_px, inner.pixel_size_um, inner.bit_depth, inner.exposure_s
        )
        self.inner = inner
        self._lock = threading.Lock()
        self._latest: NDArray[np.unsignedinteger] | None = None
        self._latest_s = -np.inf

    def _apply_exposure(self, exposure_s: float) -> None:
        with self._lock:
            self.inner.exposure_s = exposure_s

    def _grab(self) -> NDArray[np.unsignedinteger]:
        with self._lock:
            frame = self.inner.grab()
            self._latest, self._latest_s = frame, time.monotonic()
        return frame.copy()

    def latest(self, max_age_s: float) -> NDArray[np.unsignedinteger] | None:
        """The latest frame if it was grabbed within ``max_age_s`` (not a copy: read only),
        else None."""
        frame = self._latest
        if frame is None or time.monotonic() - self._latest_s > max_age_s:
            return None
        return frame

    def busy(self) -> bool:
        """True while a grab is under way."""
        return self._lock.locked()

    def _close(self) -> None:
        self.inner.close()
