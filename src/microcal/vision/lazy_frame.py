"""Frames whose pixels are made when read: a region of a frame without the rest of it.

A simulated camera renders only where the targets are, and most of a frame is background
that nobody reads: the settle loop and the vision probe look at a region of interest of a few
per cent of the frame. A :class:`RegionFrame` hands out any region of its frame (the same
pixels the whole frame has there) and the whole frame only when asked for it.

- :func:`grab_frame` grabs one frame from any camera: a region frame where the camera gives
  one (``grab_lazy``, the simulator's), else the grabbed array wrapped as one.
- :func:`detect_in` finds a target in a region of a frame (or the whole of it), as
  :func:`~microcal.vision.detect.detect` does with ``roi``.
- :func:`pixels_of` is the whole frame of a region frame or an array.
- :func:`pasted_frames` gives frames stored as a region back as region frames of full size.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Protocol, runtime_checkable

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from .detect import Detection, detect
from .targets import Target

__all__ = [
    "ArrayFrame",
    "PastedFrame",
    "RegionFrame",
    "detect_in",
    "grab_frame",
    "pasted_frames",
    "pixels_of",
]

Box = tuple[int, int, int, int]


@runtime_checkable
class RegionFrame(Protocol):
    """A frame of ``shape`` (h, w) whose pixels are read by region."""

    @property
    def shape(self) -> tuple[int, int]:
        """(height, width) of the whole frame, px."""
        ...

    def region(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.generic]:
        """The pixels of the box [x0, x1) x [y0, y1) (inside the frame), (y1 - y0, x1 - x0);
        the caller's own array."""
        ...

    def full(self) -> NDArray[np.generic]:
        """The whole frame, (h, w) (made once, then the same array)."""
        ...


class ArrayFrame:
    """A frame that is an array already (a camera that gives whole frames)."""

    def __init__(self, image: NDArray[np.generic]) -> None:
        self._image = image

    @property
    def shape(self) -> tuple[int, int]:
        h, w = self._image.shape[:2]
        return int(h), int(w)

    def region(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.generic]:
        return self._image[y0:y1, x0:x1].copy()

    def full(self) -> NDArray[np.generic]:
        return self._image


class _FrameSource(Protocol):
    def grab(self) -> NDArray[np.generic]: ...


def grab_frame(camera: _FrameSource) -> RegionFrame:
    """One frame of ``camera`` as a region frame: the camera's own (``grab_lazy()``) where
    it has one, else its ``grab()`` wrapped. Raises what the camera's grab raises."""
    lazy = getattr(camera, "grab_lazy", None)
    if callable(lazy):
        frame: RegionFrame = lazy()
        return frame
    return ArrayFrame(camera.grab())


def pixels_of(frame: RegionFrame | NDArray[np.generic]) -> NDArray[np.generic]:
    """The whole frame: an array as it is, a region frame's :meth:`RegionFrame.full`."""
    if isinstance(frame, np.ndarray):
        return frame
    return frame.full()


def detect_in(
    frame: RegionFrame | NDArray[np.generic],
    target: Target,
    roi: Box | None = None,
    previous_px: FloatArray | None = None,
) -> Detection:
    """``detect(image, target, roi=roi, previous_px=previous_px)`` on a region frame or an
    array.

    A region frame gives only the box's pixels (the box clipped to the frame); positions are
    in whole-frame pixels, and the result is the one the whole frame gives with ``roi``.
    Without ``roi``, the whole frame is searched.
    """
    if isinstance(frame, np.ndarray):
        return detect(frame, target, roi=roi, previous_px=previous_px)
    if roi is None:
        return detect(frame.full(), target, previous_px=previous_px)
    h, w = frame.shape
    x0, y0 = max(0, int(roi[0])), max(0, int(roi[1]))
    x1, y1 = min(w, int(roi[2])), min(h, int(roi[3]))
    if x1 - x0 < 8 or y1 - y0 < 8:  # detect's own answer for a box outside the image
        return detect(frame.full(), target, roi=roi)
    before = None if previous_px is None else np.subtract(previous_px, (x0, y0))
    det = detect(frame.region(x0, y0, x1, y1), target, previous_px=before)
    if det.found and (x0 or y0):
        return Detection(
            True, det.ids, np.add(det.q_px, (x0, y0)), det.quality_px, method=det.method
        )
    if not det.found and det.reason.startswith("the image has"):  # detect's words for a box
        return detect(frame.full(), target, roi=roi)
    return det


class PastedFrame:
    """A region stored from a frame, on a frame of full size filled with the region's median
    grey level (what :func:`~microcal.vision.roi.frames_from_region` gives), made only where
    it is read.

    Parameters
    ----------
    stored : (h, w) array
        The stored region.
    offset_px : (2,) int
        x0, y0 of the region in the full frame.
    full_size_px : (2,) int
        Width and height of the full frame.
    """

    def __init__(
        self, stored: NDArray[np.generic], offset_px: Sequence[int], full_size_px: Sequence[int]
    ) -> None:
        self._stored = stored
        self._x0, self._y0 = int(offset_px[0]), int(offset_px[1])
        self._w, self._h = int(full_size_px[0]), int(full_size_px[1])
        self._fill: float | None = None
        self._full: NDArray[np.generic] | None = None

    @property
    def shape(self) -> tuple[int, int]:
        return self._h, self._w

    def region(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.generic]:
        if self._full is not None:
            return self._full[y0:y1, x0:x1].copy()
        f = self._stored
        sx0, sy0 = self._x0, self._y0
        sx1, sy1 = sx0 + f.shape[1], sy0 + f.shape[0]
        if sx0 <= x0 and sy0 <= y0 and x1 <= sx1 and y1 <= sy1:  # inside the stored region
            return f[y0 - sy0 : y1 - sy0, x0 - sx0 : x1 - sx0].copy()
        if self._fill is None:
            self._fill = float(np.median(np.asarray(f, dtype=np.float64)))
        out = np.full((y1 - y0, x1 - x0), self._fill, dtype=f.dtype)
        ox0, oy0 = max(x0, sx0), max(y0, sy0)
        ox1, oy1 = min(x1, sx1, self._w), min(y1, sy1, self._h)
        if ox0 < ox1 and oy0 < oy1:
            out[oy0 - y0 : oy1 - y0, ox0 - x0 : ox1 - x0] = f[
                oy0 - sy0 : oy1 - sy0, ox0 - sx0 : ox1 - sx0
            ]
        return out

    def full(self) -> NDArray[np.generic]:
        if self._full is None:
            self._full = self.region(0, 0, self._w, self._h)
        return self._full


def pasted_frames(
    frames: Sequence[NDArray[np.generic]], offset_px: Sequence[int], full_size_px: Sequence[int]
) -> list[PastedFrame]:
    """:func:`~microcal.vision.roi.frames_from_region` made only where the frames are read."""
    return [PastedFrame(f, offset_px, full_size_px) for f in frames]
