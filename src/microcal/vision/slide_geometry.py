"""The dot positions of a printed slide, measured from its calibration views.

A slide printed on paper (or plotted on film) carries each dot a few micrometres off its
nominal lattice position: seen from several poses, each dot's reprojection residual repeats
from view to view and from camera to camera (on the DICe plate, 0.55-0.6 px of its 0.6 px
mono RMS; 0.1-0.17 px remain once each dot's own mean is taken off). Its position is then
measured along with the cameras, as in calibration with an imperfect planar target
(target-geometry refinement): each camera is calibrated alone on the current positions, every
observation's residual is carried back onto the slide's plane through that view's pose, and
each dot moves by the mean over all views and cameras that saw it. The nominal lattice fixes
the gauge: the moves are left with no mean affine part (no shift, turn, shear or scale), so
the slide's pitch along both axes stays the spec's and any error in it shows in the
triangulated pitch, not hidden in the dots.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from .._validation import FloatArray
from .detect import Detection
from .targets import Target

__all__ = ["MeasuredSlide", "measure_slide"]

#: A dot is moved once this many observations (views x cameras) have seen it.
MIN_SIGHTINGS = 4
#: Rounds of calibration and moves.
ROUNDS = 3


@dataclass(frozen=True)
class MeasuredSlide(Target):
    """A target whose features lie at measured positions (nominal plus ``offsets_um``).

    Attributes
    ----------
    offsets_um : (N, 3) float
        Each feature's measured position minus its nominal one, µm (z = 0).
    """

    offsets_um: FloatArray = field(default_factory=lambda: np.zeros((0, 3)), compare=False)

    def points_um(self) -> FloatArray:
        """Measured feature positions, (N, 3) µm."""
        nominal = super().points_um()
        if len(self.offsets_um) != len(nominal):
            return nominal
        out: FloatArray = nominal + self.offsets_um
        return out


def _plane_hit(q: FloatArray, rvec: FloatArray, tvec: FloatArray, K: FloatArray,
               dist: FloatArray) -> FloatArray:  # fmt: skip
    """Where the rays of pixels q (N, 2) meet the target plane z = 0, (N, 2) µm."""
    n = cv2.undistortPoints(q.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
    R = cv2.Rodrigues(rvec)[0]
    t = np.ravel(tvec)
    rays = np.column_stack([n, np.ones(len(n))]) @ R  # directions in the target frame
    origin = -R.T @ t
    s = -origin[2] / rays[:, 2]
    out: FloatArray = np.asarray((origin[None, :] + s[:, None] * rays)[:, :2], dtype=np.float64)
    return out


def _without_affine(nominal: FloatArray, offsets: FloatArray, moved: np.ndarray) -> FloatArray:
    """Offsets less their least-squares affine part over the moved dots."""
    A = np.column_stack([nominal[moved], np.ones(np.count_nonzero(moved))])
    coef, *_ = np.linalg.lstsq(A, offsets[moved], rcond=None)
    out: FloatArray = offsets - np.column_stack([nominal, np.ones(len(nominal))]) @ coef
    out[~moved] = 0.0
    return out


def measure_slide(
    target: Target,
    detections: Mapping[str, Sequence[Detection]],
    image_size_px: Mapping[str, tuple[int, int]],
) -> tuple[MeasuredSlide, str]:
    """Measure the dot positions of a slide from every camera's views.

    Parameters
    ----------
    target : Target
    detections : dict camera -> list of Detection
    image_size_px : dict camera -> (width, height)

    Returns
    -------
    slide : MeasuredSlide
        The target with measured positions (its nominal ones where too few views saw a dot).
    note : str
        One line on what was measured ("" when nothing was: too few views).
    """
    nominal = Target.points_um(target)
    offsets = np.zeros_like(nominal)
    moved = np.zeros(len(nominal), dtype=bool)
    for _ in range(ROUNDS):
        points = nominal + offsets
        sums = np.zeros((len(nominal), 2))
        counts = np.zeros(len(nominal))
        for cam, dets in detections.items():
            found = [d for d in dets if d.found and len(d.ids) >= 8]
            if len(found) < 3:
                continue
            obj = [points[d.ids].astype(np.float32) for d in found]
            img = [d.q_px.astype(np.float32) for d in found]
            try:
                _, K, dist, rvecs, tvecs = cv2.calibrateCamera(
                    obj, img, image_size_px[cam], None, None, flags=cv2.CALIB_FIX_K3
                )
            except cv2.error:
                continue
            for d, rv, tv in zip(found, rvecs, tvecs, strict=True):
                hit = _plane_hit(d.q_px, rv, tv, K, dist)
                np.add.at(sums, d.ids, hit - points[d.ids, :2])
                np.add.at(counts, d.ids, 1.0)
        moved = counts >= MIN_SIGHTINGS
        if np.count_nonzero(moved) < 6:
            return _measured(target, np.zeros_like(nominal)), ""
        step = np.zeros_like(nominal)
        step[moved, :2] = sums[moved] / counts[moved, None]
        offsets = offsets + step
        offsets[:, :2] = _without_affine(nominal[:, :2], offsets[:, :2], moved)
    size = np.linalg.norm(offsets[moved, :2], axis=1)
    slide = _measured(target, offsets)
    note = (
        f"the slide's {np.count_nonzero(moved)} dots seen in {MIN_SIGHTINGS} or more views "
        f"measured: {float(np.sqrt(np.mean(size**2))):.2f} µm RMS from the nominal lattice "
        f"(at most {float(size.max()):.2f} µm)"
    )
    return slide, note


def _measured(target: Target, offsets_um: FloatArray) -> MeasuredSlide:
    return MeasuredSlide(target.kind, target.cols, target.rows, target.pitch_um,
                         target.feature_um, target.first_marker, target.markers,
                         offsets_um)  # fmt: skip
