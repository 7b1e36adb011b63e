"""The virtual point (thesis Eq 4.13): the mean of a board's inner corners, and its uncertainty.

The thesis represents the end-effector by the mean of the N inner corners; averaging makes
it several times steadier than one corner (Table 4-1). The mean is taken over *undistorted*
corners when the camera is known, so it is the image of the corners' 3D centroid under the
pinhole model (to far below the noise for a small board). Its covariance comes from the
corners' residuals about a plane homography: ``s² = RSS / (2N - 8)`` per coordinate, and
``cov = s² / N * I``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DetectionError
from ..geometry.camera_kinds import AnyCamera
from .detect import Detection
from .targets import Target

__all__ = ["VirtualPoint", "virtual_point"]


@dataclass(frozen=True)
class VirtualPoint:
    """The virtual point of one detection.

    Attributes
    ----------
    q_px : (2,) float
        Mean of the corners: undistorted (ideal pinhole pixels) when a camera was given.
    cov_px2 : (2, 2) float
        Its covariance from the corner residuals.
    residual_px : float
        RMS residual of one corner about the homography (the one-corner noise).
    n : int
        Corners averaged.
    """

    q_px: FloatArray
    cov_px2: FloatArray
    residual_px: float
    n: int


def virtual_point(
    detection: Detection, target: Target, camera: AnyCamera | None = None
) -> VirtualPoint:
    """Mean of the detected corners (Eq 4.13) with its uncertainty.

    Parameters
    ----------
    detection : Detection
        A chessboard (or ChArUco) detection with all corners (a partial board would move the
        mean).
    target : Target
    camera : CameraModel or AffineCamera, optional
        When given, corners are undistorted before averaging.

    Raises
    ------
    DetectionError
        Nothing found, or not every corner of the board.
    """
    if not detection.found:
        raise DetectionError(f"virtual point: no board detected ({detection.reason})")
    n_all = target.pattern_size[0] * target.pattern_size[1]
    if len(detection.ids) != n_all:
        raise DetectionError(
            f"virtual point: expected all {n_all} corners, got {len(detection.ids)} "
            f"(board partly hidden?)"
        )
    q = detection.q_px if camera is None else camera.undistort_px(detection.q_px)
    plane = target.points_um()[detection.ids, :2]
    H, _ = cv2.findHomography(plane, q, 0)
    proj = cv2.perspectiveTransform(plane.reshape(-1, 1, 2), H).reshape(-1, 2)
    rss = float(np.sum((proj - q) ** 2))
    n = len(q)
    s2 = rss / max(2 * n - 8, 1)
    return VirtualPoint(q.mean(axis=0), np.eye(2) * s2 / n, float(np.sqrt(s2)), n)
