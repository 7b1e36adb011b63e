"""What a camera calibration yields, and the helpers both methods share.

:class:`CameraCalibration` (one camera and the figures that qualify it) and
:class:`StereoCalibration` (all cameras in one {V}); outlier views (above
:data:`OUTLIER_FACTOR` times the median view and :data:`OUTLIER_FLOOR_PX`), a camera model
from OpenCV's results, a detection renumbered by a turn of its board.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypedDict, TypeVar

import cv2
import numpy as np

from .._validation import FloatArray
from ..geometry import AnyCamera, CameraModel
from ..json_value import JsonValue
from .board_symmetry import turn_ids
from .calibration_diagnostics import CameraDiagnostics
from .detect import Detection
from .targets import Target
from .view_consistency import rotation_angle_deg

ViewT = TypeVar("ViewT")
ResultT = TypeVar("ResultT")

__all__ = [
    "OUTLIER_FACTOR",
    "OUTLIER_FLOOR_PX",
    "OUTLIER_ROUNDS",
    "CameraCalibration",
    "StereoCalibration",
    "TurnedView",
]

#: A view is an outlier when its RMS exceeds this many times the median view's ...
OUTLIER_FACTOR = 3.0
#: ... and this many pixels.
OUTLIER_FLOOR_PX = 0.15
#: Rounds of rejection at most; the fit after the last round is the one returned.
OUTLIER_ROUNDS = 3


class TurnedView(TypedDict):
    """An image whose corner numbering was turned to agree (a symmetric board)."""

    image: str
    camera: str
    turn_deg: int


@dataclass
class CameraCalibration:
    """One calibrated camera and the figures that qualify it."""

    model: AnyCamera
    rms_px: float
    per_view_rms_px: dict[str, float]
    views_used: int
    views_rejected: list[dict[str, str]] = field(default_factory=list)
    std: dict[str, list[float]] = field(default_factory=dict)
    residuals_px: dict[str, FloatArray] = field(default_factory=dict)
    """Per used view, (N, 4): detected x, y and reprojection residual dx, dy (projected
    minus detected), px."""
    lens_model: dict[str, object] = field(default_factory=dict)
    """Method (b): ``name``, ``reason``, ``field_of_view_deg`` and the ``candidates`` tried
    (each with its training and held-out RMS)."""
    diagnostics: CameraDiagnostics | None = None
    """Method (b): uncertainty, split-half check, coverage and verdict."""
    model_choice: dict[str, object] = field(default_factory=dict)
    """Method (a) with a choice of camera model: ``chosen``, ``reason`` and the
    ``candidates`` tried (each with its training and held-out RMS and whether its fit is
    ill-conditioned)."""


@dataclass
class StereoCalibration:
    """All cameras, in one {V}."""

    method: str
    cameras: dict[str, CameraCalibration]
    rms_px: float
    baseline_um: float
    turned_views: list[TurnedView] = field(default_factory=list)
    """Images whose corner numbering was turned (a symmetric board): ``image``, ``camera``,
    ``turn_deg``. Method (b): to agree with the first camera's in the same view; method (a):
    with the same camera's first view, or as its steps across the target's plane fit."""
    views_rejected: list[dict[str, str]] = field(default_factory=list)
    """View pairs left out of the stereo solve: ``view`` (both images) and ``reason``."""
    notes: list[str] = field(default_factory=list)
    """Warnings about the calibration as a whole, one sentence each."""
    consistency: dict[str, JsonValue] = field(default_factory=dict)
    """Figures that need no reference (method (b)): held-out views' error, the triangulated
    target pitch, transforms composed through a third camera
    (:mod:`~microcal.vision.calibration_consistency`); empty when not computed."""

    def models(self) -> dict[str, AnyCamera]:
        """The camera models by name."""
        return {name: c.model for name, c in self.cameras.items()}

    @property
    def angle_deg(self) -> float:
        """Angle between the first two cameras' optical axes' frames (rotation angle), deg."""
        models = list(self.models().values())
        if len(models) < 2:
            return 0.0
        return rotation_angle_deg(models[1].R, models[0].R)


def _camera_model(
    K: Any, dist: Any, rvec: Any, tvec: Any, size: tuple[int, int], name: str
) -> CameraModel:
    R, _ = cv2.Rodrigues(np.asarray(rvec, dtype=np.float64))
    K = np.asarray(K, dtype=np.float64).copy()
    K[1, 0] = K[2, 0] = K[2, 1] = 0.0
    K[2, 2] = 1.0
    d = np.asarray(dist, dtype=np.float64).ravel()  # OpenCV's lengths are CameraModel's
    # Re-orthonormalise R against rounding in Rodrigues.
    u, _, vt = np.linalg.svd(R)
    return CameraModel(K, d, u @ vt, np.asarray(tvec, dtype=np.float64).ravel(), size, name)


def _residuals(projected_px: FloatArray, detected_px: FloatArray) -> FloatArray:
    return np.hstack([detected_px, projected_px - detected_px])


def _outliers(rms: Mapping[ViewT, float]) -> dict[ViewT, str]:
    if len(rms) < 3:
        return {}
    median = float(np.median(list(rms.values())))
    limit = max(OUTLIER_FACTOR * median, OUTLIER_FLOOR_PX)
    return {
        view: f"reprojection RMS {value:.3f} px > {limit:.3f} px "
        f"({OUTLIER_FACTOR:g}x the median view)"
        for view, value in rms.items()
        if value > limit
    }


def _fit_rejecting_outliers(
    views: Sequence[ViewT], fit: Callable[[list[ViewT]], tuple[ResultT, Mapping[ViewT, float]]]
) -> tuple[ResultT, list[ViewT], dict[ViewT, str]]:
    """Fit, drop the views whose RMS stands out, fit again, :data:`OUTLIER_ROUNDS` rounds at
    most; the fit returned is always of the views kept.

    Parameters
    ----------
    views : sequence
        The views to start from.
    fit : callable (views) -> (result, {view: RMS px})
        Fits the views given (raising when they are too few) and gives each one's RMS.

    Returns
    -------
    result, kept views, {rejected view: reason}
    """
    kept = list(views)
    rejected: dict[ViewT, str] = {}
    for round_ in range(OUTLIER_ROUNDS + 1):
        result, rms = fit(kept)
        bad = _outliers(rms)
        if not bad or round_ == OUTLIER_ROUNDS:
            break
        rejected.update(bad)
        kept = [v for v in kept if v not in bad]
    return result, kept, rejected


def _usable(
    detections: Sequence[Detection], names: Sequence[str]
) -> tuple[list[int], list[dict[str, str]]]:
    used, rejected = [], []
    for i, (det, name) in enumerate(zip(detections, names, strict=True)):
        if det.found:
            used.append(i)
        else:
            rejected.append({"image": name, "reason": det.reason or "target not found"})
    return used, rejected


def _renumbered(det: Detection, target: Target, turn_deg: int) -> Detection:
    """The detection with its ids renumbered as the board turned by ``turn_deg``."""
    if turn_deg == 0:
        return det
    ids = turn_ids(target, turn_deg)[det.ids]
    order = np.argsort(ids)
    return Detection(True, ids[order], det.q_px[order], det.quality_px, method=det.method)


def _baseline(models: Mapping[str, AnyCamera]) -> float:
    """Distance between the first two cameras' projection centres, µm; NaN when either is
    affine (it has no centre)."""
    first = list(models.values())[:2]
    if len(first) < 2:
        return 0.0
    if not all(isinstance(m, CameraModel) for m in first):
        return float("nan")
    a, b = (m.centre_um for m in first if isinstance(m, CameraModel))
    return float(np.linalg.norm(a - b))
