"""The vision probe: where the end-effector is now, measured from fresh frames of every camera."""

from __future__ import annotations

from collections.abc import Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import DeviceTimeoutError, FrameError
from ..geometry import AnyCamera
from .lazy_frame import RegionFrame, grab_frame
from .measurement import camera_view, measure_seen
from .roi import RoiPredictor
from .targets import Target
from .tip_target import TipTarget
from .view_agreement import refuse_disagreeing

__all__ = ["FrameSource", "VisionProbe"]

#: Times a frame is grabbed again after a dropped frame or a timeout (as acquisition does).
GRAB_RETRIES = 3


class FrameSource(Protocol):
    """Anything that gives a frame on request (every camera of ``microcal.devices``)."""

    def grab(self) -> NDArray[np.generic]:
        """One frame, (h, w)."""
        ...


@dataclass
class VisionProbe:
    """Measures the end-effector now: grabs frames from every camera, triangulates.

    The board's region in each image is predicted from the joints of the poses measured
    before (:class:`~microcal.vision.roi.RoiPredictor`), as the acquisition does.
    """

    cameras: Mapping[str, FrameSource]
    models: dict[str, AnyCamera]
    target: Target | TipTarget
    frames: int = 5
    frame_cov_px2: dict[str, FloatArray] | None = None
    search_threads: bool = True  # each camera's frames searched on a thread (False: in turn)
    _predictors: dict[str, RoiPredictor] = field(default_factory=dict)
    #: Why the last measurement found nothing, camera by camera (``top: tip out of the
    #: field``); empty after one that found the target.
    last_reason: str = field(default="", init=False)
    #: Every measurement that found nothing: its joints (3,) µm and the cameras' reasons.
    failures: list[tuple[FloatArray, str]] = field(default_factory=list, init=False)

    def learn_regions(self, d_um: FloatArray, corners_px: Mapping[str, FloatArray]) -> None:
        """Where the board was at joints ``d_um`` (3,): its corners (k, 2) px per camera, as an
        acquisition found them; the probe's first measurements then look there rather than
        over the whole frame (cameras the probe lacks are left out)."""
        for n, corners in corners_px.items():
            if n in self.cameras:
                self._predictors.setdefault(n, RoiPredictor()).add(d_um, corners)

    def measure(self, d_um: FloatArray) -> FloatArray:
        """Position in {G} (3,) µm from :attr:`frames` frames; NaN when the board is not found."""
        return self.measure_with_covariance(d_um, self.frames)[0]

    def measure_with_covariance(
        self, d_um: FloatArray, frames: int
    ) -> tuple[FloatArray, FloatArray]:
        """Position in {G} (3,) µm and its covariance (3, 3) µm² from ``frames`` frames per
        camera; NaN when the board is not found."""
        rois = {
            n: self._predictors.setdefault(n, RoiPredictor()).predict(d_um) for n in self.cameras
        }
        # each camera's frames are searched on a thread of their own while the next camera's
        # are grabbed (rendered); what each camera makes of its frames does not depend on
        # the others'
        # (without search_threads each camera's frames are searched once grabbed: the same
        # views, for a process that has no core to spare)
        threads = len(self.cameras) if self.search_threads else 1
        with ThreadPoolExecutor(max_workers=threads) as searchers:
            views = {}
            for n, cam in self.cameras.items():
                grabbed = [_grab(cam) for _ in range(frames)]
                if n in self.models:
                    views[n] = searchers.submit(
                        camera_view, grabbed, self.target, self.models[n], rois[n]
                    )
                    if not self.search_threads:
                        views[n].result()
            seen = {n: view.result() for n, view in views.items()}
        m = measure_seen(seen, self.models, self.frame_cov_px2)
        if isinstance(self.target, TipTarget):  # one tip each camera, maybe each another tool's
            refuse_disagreeing([m], self.models)
        self.last_reason = "" if m.status == "ok" else m.reason
        if m.status != "ok":
            self.failures.append((np.array(d_um, dtype=np.float64), m.reason))
            return np.full(3, np.nan), np.full((3, 3), np.nan)
        for n in self.cameras:
            if n in m.corners_px:
                self._predictors[n].add(d_um, m.corners_px[n])
        return m.p_um, m.cov_um2


def _grab(camera: FrameSource) -> RegionFrame:
    """One frame (read where it is searched, :func:`~microcal.vision.lazy_frame.grab_frame`),
    grabbed again up to :data:`GRAB_RETRIES` times after a dropped frame or a timeout; the
    last such error is raised."""
    for attempt in range(GRAB_RETRIES + 1):
        try:
            return grab_frame(camera)
        except (FrameError, DeviceTimeoutError):
            if attempt == GRAB_RETRIES:
                raise
    raise AssertionError("unreachable")
