"""The station with one camera: where the tip is, and where a click sends it.

One camera sees across its optical axis, not along it. :class:`OneCameraProbe` measures the
tip across the axis from the camera (the target's virtual point in the image) and takes its
depth along the axis from the calibration's prediction for the joints (the model, not the
camera); its covariance says so: the camera's uncertainty across, the model's along. A closed
loop on it corrects the tip across the camera's axis and leaves the depth to the model (open
loop along the axis).

:class:`FocalPlane` is the plane a click is taken to: perpendicular to the camera's axis at its
depth of best focus. The camera's calibration does not hold where it focuses, so the plane is
set where the tip is when the station opens (the tip in focus, as one works at a microscope)
and set again on request; the page adds an offset along the axis.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..geometry import AnyCamera
from ..geometry.focal_plane import point_at_depth_with_cov
from ..vision.measurement import _vp_of_frames
from ..vision.probe import FrameSource, _grab
from ..vision.roi import RoiPredictor
from ..vision.targets import Target

__all__ = ["DEPTH_STD_FLOOR_UM", "FocalPlane", "OneCameraProbe", "axis_variance_um2"]

#: The smallest standard deviation of a depth taken from the model, µm (a calibration taken
#: from the truth says 0; the covariance stays invertible).
DEPTH_STD_FLOOR_UM = 0.1

#: The calibration's prediction for joints: position (3,) µm and covariance (3, 3) µm².
Predict = Callable[[FloatArray], tuple[FloatArray, FloatArray]]


def axis_variance_um2(camera: AnyCamera, cov_um2: FloatArray) -> float:
    """The variance (µm²) along ``camera``'s optical axis of a covariance (3, 3) in {G}, at
    least :data:`DEPTH_STD_FLOOR_UM` squared."""
    axis = np.asarray(camera.R[2], dtype=np.float64)
    return max(float(axis @ cov_um2 @ axis), DEPTH_STD_FLOOR_UM**2)


@dataclass
class FocalPlane:
    """The camera's plane of best focus: its depth along the camera's axis, µm, and that
    depth's variance, µm² (where it was set from)."""

    camera: AnyCamera
    depth_um: float
    depth_var_um2: float
    source: str

    @classmethod
    def through(
        cls, camera: AnyCamera, p_um: FloatArray, cov_um2: FloatArray, source: str
    ) -> FocalPlane:
        """The plane through a point (3,) of {G} with covariance (3, 3)."""
        depth = float(camera.depth_um(p_um[None, :])[0])
        return cls(camera, depth, axis_variance_um2(camera, cov_um2), source)

    def target(
        self, q_px: ArrayLike, click_std_px: float, offset_um: float = 0.0
    ) -> tuple[FloatArray, FloatArray]:
        """The point (3,) µm a click ``q_px`` (2,) (distortion included) with its standard
        deviation (px) gives on the plane moved ``offset_um`` along the axis (away from the
        camera), and its covariance (3, 3) µm²."""
        q = as_array(q_px, "click", (2,))
        return point_at_depth_with_cov(self.camera, q, self.depth_um + float(offset_um),
                                       click_std_px**2 * np.eye(2), self.depth_var_um2)  # fmt: skip

    def as_dict(self) -> dict[str, object]:
        """Plain dict for JSON."""
        return {"depth_um": self.depth_um, "depth_std_um": float(np.sqrt(self.depth_var_um2)),
                "source": self.source}  # fmt: skip


@dataclass
class OneCameraProbe:
    """Measures the tip with one camera (module docstring): ``measure_with_covariance`` as
    :class:`~microcal.vision.probe.VisionProbe`'s."""

    camera: FrameSource
    model: AnyCamera
    target: Target
    predict: Predict
    frames: int = 5

    def __post_init__(self) -> None:
        self._predictor = RoiPredictor()

    def measure_with_covariance(
        self, d_um: FloatArray, frames: int
    ) -> tuple[FloatArray, FloatArray]:
        """Position in {G} (3,) µm and its covariance (3, 3) µm² from ``frames`` frames; NaN
        when the target is not found."""
        grabbed = [_grab(self.camera) for _ in range(frames)]
        got = _vp_of_frames(grabbed, self.target, self.model, self._predictor.predict(d_um))
        if isinstance(got, str):
            return np.full(3, np.nan), np.full((3, 3), np.nan)
        vps, cov_px2, corners = got
        self._predictor.add(d_um, corners)
        sigma = float(getattr(self.model, "projection_sigma_px", 0.0))
        cov_q = cov_px2 / len(vps) + sigma**2 * np.eye(2)
        p_model, cov_model = self.predict(np.asarray(d_um, dtype=np.float64))
        depth = float(self.model.depth_um(p_model[None, :])[0])
        var = axis_variance_um2(self.model, cov_model)
        return point_at_depth_with_cov(self.model, vps.mean(axis=0), depth, cov_q, var)
