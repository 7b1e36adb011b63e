"""The virtual point (thesis Eq 4.13): the mean of a board's inner corners, and its uncertainty.

The thesis represents the end-effector by the mean of the N inner corners; averaging makes
it several times steadier than one corner (Table 4-1). The mean is taken over *undistorted*
corners when the camera is known, so it is the image of the corners' 3D centroid under the
pinhole model (to far below the noise for a small board). Its covariance comes from the
corners' residuals about a plane homography: ``s² = RSS / (2N - 8)`` per coordinate, and
``cov = s² / N * I``.

A target numbered from markers (a dot grid or chessboard of which any part may be in view)
has no mean of its corners that stays put: the part seen changes from view to view. Its
virtual point is the picture of one fixed point of the target, its centre
(:attr:`~microcal.vision.targets.Target.centre_um`, the mean of all its grid points), mapped
by the plane homography fitted to the features seen, each by its number on the target. Under
a pinhole or affine camera, undistorted pixels of a plane are exactly a homography of it, so
whatever part is seen the point is the same target point; its covariance is that of the
fitted homography at the centre (``s²`` as above, propagated through the fit): about
``s² / N`` where the centre is among the features seen, growing as it is extrapolated.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DetectionError
from ..geometry.camera_kinds import AnyCamera
from .detect import Detection
from .targets import Target

__all__ = ["MIN_ANCHORED_FEATURES", "VirtualPoint", "anchored_point", "virtual_point"]

#: Features needed for the virtual point of a target numbered from markers (a homography
#: has 8 parameters; a few more give its residual's scale).
MIN_ANCHORED_FEATURES = 8


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
        mean); for a target numbered from markers, any :data:`MIN_ANCHORED_FEATURES` or more
        features (the picture of the target's centre, see the module's docstring).
    target : Target
    camera : CameraModel or AffineCamera, optional
        When given, corners are undistorted before averaging.

    Raises
    ------
    DetectionError
        Nothing found, or not every corner of the board (too few features of a target
        numbered from markers).
    """
    if not detection.found:
        raise DetectionError(f"virtual point: no board detected ({detection.reason})")
    if target.partial:
        return anchored_point(detection, target, camera)
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


def _normalising(points: FloatArray) -> FloatArray:
    """(3, 3) similarity taking points (N, 2) to zero mean and unit RMS distance."""
    mean = points.mean(axis=0)
    scale = float(np.sqrt(np.mean(np.sum((points - mean) ** 2, axis=1))))
    scale = 1.0 / scale if scale > 0 else 1.0
    return np.array([[scale, 0.0, -scale * mean[0]], [0.0, scale, -scale * mean[1]],
                     [0.0, 0.0, 1.0]])  # fmt: skip


def _mapped_and_jacobian(h: FloatArray, g: FloatArray) -> tuple[FloatArray, FloatArray]:
    """Points (N, 2) mapped by the homography of parameters h (8,) (H[2, 2] = 1), and the
    derivatives of the mapped points by h, (N, 2, 8)."""
    x, y = g[:, 0], g[:, 1]
    w = h[6] * x + h[7] * y + 1.0
    u = (h[0] * x + h[1] * y + h[2]) / w
    v = (h[3] * x + h[4] * y + h[5]) / w
    one, zero = np.ones_like(x), np.zeros_like(x)
    du = np.stack([x, y, one, zero, zero, zero, -u * x, -u * y], axis=1) / w[:, None]
    dv = np.stack([zero, zero, zero, x, y, one, -v * x, -v * y], axis=1) / w[:, None]
    return np.column_stack([u, v]), np.stack([du, dv], axis=1)


def anchored_point(
    detection: Detection, target: Target, camera: AnyCamera | None = None
) -> VirtualPoint:
    """The picture of a target's centre from any part of it seen (a target with markers).

    Parameters
    ----------
    detection : Detection
        Features of the target, numbered (``ids`` into ``target.points_um()``); any part.
    target : Target
    camera : CameraModel or AffineCamera, optional
        When given, the features are undistorted first (the homography then holds exactly).

    Returns
    -------
    VirtualPoint
        ``q_px``: the target's centre mapped by the homography fitted (least squares on the
        pixel residuals) to the features seen; ``cov_px2``: the homography's covariance at
        the centre, from the features' residual scatter.

    Raises
    ------
    DetectionError
        Fewer than :data:`MIN_ANCHORED_FEATURES` features, or all on one line.
    """
    n = len(detection.ids)
    if n < MIN_ANCHORED_FEATURES:
        raise DetectionError(
            f"virtual point: {n} features of the target seen, {MIN_ANCHORED_FEATURES} or more "
            f"needed"
        )
    q = detection.q_px if camera is None else camera.undistort_px(detection.q_px)
    plane = target.points_um()[detection.ids, :2]
    if np.linalg.matrix_rank(plane - plane.mean(axis=0), tol=1e-6 * target.pitch_um) < 2:
        raise DetectionError("virtual point: the features seen lie on one line")
    # fitted in normalised coordinates (plane and pixels): a well-conditioned least squares
    Tg, Tq = _normalising(plane), _normalising(q)
    g = plane @ Tg[:2, :2].T + Tg[:2, 2]
    qn = q @ Tq[:2, :2].T + Tq[:2, 2]
    H0: Any = cv2.findHomography(g, qn, 0)[0]
    if H0 is None:
        raise DetectionError("virtual point: no homography through the features seen")
    h = (np.asarray(H0, dtype=np.float64) / H0[2, 2]).ravel()[:8]
    for _ in range(5):  # Gauss-Newton on the pixel residuals (from the DLT's start)
        mapped, J = _mapped_and_jacobian(h, g)
        r = (qn - mapped).ravel()
        A = J.reshape(-1, 8)
        h = h + np.linalg.lstsq(A, r, rcond=None)[0]
    mapped, J = _mapped_and_jacobian(h, g)
    A = J.reshape(-1, 8)
    scale = Tq[0, 0]  # normalised units per pixel
    rss = float(np.sum((qn - mapped) ** 2)) / scale**2
    s2 = rss / max(2 * n - 8, 1)
    centre = target.centre_um[None, :2] @ Tg[:2, :2].T + Tg[:2, 2]
    c_n, dc = _mapped_and_jacobian(h, centre)
    # covariance of h: s² (AᵀA)⁻¹ in normalised pixels², carried to the centre's picture
    cov_n = dc[0] @ np.linalg.pinv(A.T @ A) @ dc[0].T
    q0 = (c_n[0] - Tq[:2, 2]) / scale
    return VirtualPoint(q0, cov_n * s2, float(np.sqrt(s2)), n)
