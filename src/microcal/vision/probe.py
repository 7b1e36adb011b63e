"""The vision probe: where the end-effector is now, measured from fresh frames of every camera."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Protocol

import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import DeviceTimeoutError, FrameError
from ..geometry import AnyCamera
from .measurement import measure_one
from .roi import RoiPredictor
from .targets import Target
from .tip_target import TipTarget

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
    _predictors: dict[str, RoiPredictor] = field(default_factory=dict)

    def measure(self, d_um: FloatArray) -> FloatArray:
        """Position in {G} (3,) µm from :attr:`frames` frames; NaN when the board is not found."""
        return self.measure_with_covariance(d_um, self.frames)[0]

    def measure_with_covariance(
        self, d_um: FloatArray, frames: int
    ) -> tuple[FloatArray, FloatArray]:
        """Position in {G} (3,) µm and its covariance (3, 3) µm² from ``frames`` frames per
        camera; NaN when the board is not found."""
        grabbed = {n: [_grab(cam) for _ in range(frames)] for n, cam in self.cameras.items()}
        rois = {
            n: self._predictors.setdefault(n, RoiPredictor()).predict(d_um) for n in self.cameras
        }
        m = measure_one(grabbed, self.models, self.target, rois, self.frame_cov_px2)
        if m.status != "ok":
            return np.full(3, np.nan), np.full((3, 3), np.nan)
        for n in self.cameras:
            if n in m.corners_px:
                self._predictors[n].add(d_um, m.corners_px[n])
        return m.p_um, m.cov_um2


def _grab(camera: FrameSource) -> NDArray[np.generic]:
    """One frame, grabbed again up to :data:`GRAB_RETRIES` times after a dropped frame or a
    timeout; the last such error is raised."""
    for attempt in range(GRAB_RETRIES + 1):
        try:
            return camera.grab()
        except (FrameError, DeviceTimeoutError):
            if attempt == GRAB_RETRIES:
                raise
    raise AssertionError("unreachable")
