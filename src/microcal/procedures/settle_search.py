"""The settle loop's searches on another core: a forked process that finds the board in each
frame while the next frame is rendered.

The settle loop searches every frame in the box around the corners the frame before gave,
from those corners (:class:`~microcal.procedures.acquisition._FrameSearch`), so the searches
form a chain. A
:class:`ForkedSearcher` runs that chain in a process forked at the start of the run: for each
frame it is sent a crop of the frame (the pose's predicted region, grown by
:data:`CROP_MARGIN_PX`), which holds the box searched whenever the board is near where it
was predicted; the pixels are the frame's own, so the corners found are the ones a search
here finds. When a search would read outside the crop (the board elsewhere, or a search of
the whole frame), the process stops searching that pose and says where the chain stood; this
process then searches that frame and the pose's later ones itself, in order, from there. So
the corners of every frame are those of searching each frame here, in turn, and what the
loop decides is unchanged.
"""

from __future__ import annotations

import multiprocessing
import weakref
from collections.abc import Callable
from multiprocessing import get_context
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from .._parallel import can_fork, end_helper, ignore_interrupts, parent_messages
from .._validation import FloatArray
from ..vision.lazy_frame import RegionFrame

__all__ = ["CROP_MARGIN_PX", "ForkedSearcher", "Search"]

#: How far the crop sent for each frame reaches beyond the pose's predicted region, px.
CROP_MARGIN_PX = 16

Box = tuple[int, int, int, int]
#: Where a chain of searches stands: the region searched next and the corners found last.
State = tuple[Box | None, FloatArray | None]


class Search(Protocol):
    """One pose's chain of searches: each frame searched where the one before found the board."""

    @property
    def state(self) -> State: ...

    def corners(self, frame: RegionFrame) -> FloatArray | None: ...


class _OutsideCropError(Exception):
    """A search asked for pixels outside the crop it was sent."""


class _CropFrame:
    """A frame of which only a crop is known; reading elsewhere raises
    :class:`_OutsideCropError`."""

    def __init__(self, crop: NDArray[np.generic], box: Box, shape: tuple[int, int]) -> None:
        self._crop = crop
        self._box = box
        self._shape = shape

    @property
    def shape(self) -> tuple[int, int]:
        return self._shape

    def region(self, x0: int, y0: int, x1: int, y1: int) -> NDArray[np.generic]:
        bx0, by0, bx1, by1 = self._box
        if x0 < bx0 or y0 < by0 or x1 > bx1 or y1 > by1:
            raise _OutsideCropError
        return self._crop[y0 - by0 : y1 - by0, x0 - bx0 : x1 - bx0].copy()

    def full(self) -> NDArray[np.generic]:
        raise _OutsideCropError


def _serve(make_search: Callable[[State], Search], conn: Any, other: Any) -> None:
    """The forked process: poses and frames in, corners (or where the chain stopped) out
    (``other``, the run's end of the pipe, closed here)."""
    other.close()
    ignore_interrupts()
    search: Search | None = None
    stopped = False
    for message in parent_messages(conn):
        kind = message[0]
        if kind == "end":
            return
        if kind == "pose":
            search, stopped = make_search((message[1], None)), False
            continue
        _, crop, box, shape = message
        if stopped or search is None:
            conn.send(("skipped", None))
            continue
        state = search.state
        try:
            conn.send(("found", search.corners(_CropFrame(crop, box, shape))))
        except Exception:  # outside the crop, or an error: searched there again, in turn
            stopped = True
            conn.send(("here", state))


class ForkedSearcher:
    """A forked process searching the settle loop's frames (see the module docstring).

    Parameters
    ----------
    make_search : callable ((roi, corners)) -> Search
        A pose's chain of searches, starting in ``roi`` from ``corners`` (None at a pose's
        start; the same here and there).
    """

    def __init__(self, make_search: Callable[[State], Search]) -> None:
        self.make_search = make_search
        self.searched_here = 0  # frames the forked process left to this one
        self._proc: Any = None
        self._conn: Any = None
        if can_fork() and not multiprocessing.current_process().daemon:
            ctx = get_context("fork")
            here, there = ctx.Pipe(duplex=True)
            self._proc = ctx.Process(target=_serve, args=(make_search, there, here), daemon=True)
            self._proc.start()
            there.close()
            self._conn = here
            self._finalizer = weakref.finalize(self, end_helper, self._proc, here, ("end",))

    @property
    def forked(self) -> bool:
        return self._proc is not None

    def pose(self, roi: Box, shape: tuple[int, int]) -> PoseSearch:
        """A pose's searches, from the pose's predicted region ``roi`` in frames of ``shape``
        (height, width)."""
        self._conn.send(("pose", roi))
        h, w = shape
        box = (max(0, roi[0] - CROP_MARGIN_PX), max(0, roi[1] - CROP_MARGIN_PX),
               min(w, roi[2] + CROP_MARGIN_PX), min(h, roi[3] + CROP_MARGIN_PX))  # fmt: skip
        return PoseSearch(self, roi, box)

    def close(self) -> None:
        """End the process."""
        if self._proc is not None:
            end_helper(self._proc, self._conn, ("end",))
            self._proc = None


class PoseSearch:
    """One pose's frames, each sent to the process one grab later (so that a frame still
    being painted elsewhere, :mod:`microcal.sim.paint_process`, is read once the next one is
    under way); :meth:`corners` gives their corners in order (searched here from where the
    process stopped, if it did)."""

    def __init__(self, owner: ForkedSearcher, roi: Box, box: Box) -> None:
        self._owner = owner
        self._box = box
        self._here: Search | None = None  # the chain, once it continues here
        self._roi = roi
        self._sent: list[RegionFrame] = []
        self._posted = 0  # frames sent to the process so far
        self._read = 0

    def submit(self, frame: RegionFrame) -> int:
        """Take a frame (the one before is sent now); returns its number for
        :meth:`corners`."""
        self._post(len(self._sent))
        self._sent.append(frame)
        return len(self._sent) - 1

    def _post(self, upto: int) -> None:
        """Send the frames before number ``upto`` not sent yet."""
        x0, y0, x1, y1 = self._box
        while self._posted < upto:
            frame = self._sent[self._posted]
            if self._here is None:
                crop = frame.region(x0, y0, x1, y1)
                self._owner._conn.send(("frame", crop, self._box, frame.shape))
            else:  # the process stopped: nothing more is sent for this pose
                self._owner._conn.send(("frame", None, self._box, frame.shape))
            self._posted += 1

    def corners(self, k: int) -> FloatArray | None:
        """The corners of frame ``k`` (frames are asked for in order)."""
        if k != self._read:
            raise RuntimeError(f"settle search: frame {k} asked for before frame {self._read}")
        self._post(k + 1)
        self._read += 1
        if not self._owner._conn.poll(None):  # pragma: no cover - poll(None) waits
            raise RuntimeError("settle search: no answer")
        kind, value = self._owner._conn.recv()
        if kind == "found" and self._here is None:
            out: FloatArray | None = value
            return out
        if self._here is None:  # "here": the chain continues here from where it stood
            self._here = self._owner.make_search(value)
        self._owner.searched_here += 1
        return self._here.corners(self._sent[k])
