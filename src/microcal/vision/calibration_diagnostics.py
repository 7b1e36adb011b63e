"""How far a camera calibration can be trusted: uncertainty, split-half check, a verdict.

- **Covariance of the intrinsics** (:func:`intrinsics_covariance`): first order,
  ``sigma^2 (J^T J)^-1`` over every free parameter (intrinsics and each view's board pose),
  the poses eliminated by their Schur complement; ``sigma`` from the residuals.
- **Projection uncertainty** (:func:`projection_uncertainty_px`): the 1-sigma error, in the
  worst direction, of projecting a point through the calibrated intrinsics, over a grid of
  the image. A change of intrinsics that a small rotation of the camera undoes (the principal
  point against the camera's pointing) moves no measurement made with the calibrated
  extrinsics, so that part is removed: the change is taken after the best-fitting rotation
  over the grid. (mrcal's method follows the target frames instead; this is its linear,
  camera-centred cousin.)
- **Split-half check** (:func:`split_half`): the views dealt into two halves, each calibrated
  alone; their projections are compared over the image after the best-fitting rotation, and
  set against what the two halves' uncertainties predict. Halves that disagree more than
  predicted point at the lens model or the detection; halves that disagree by much in pixels
  point at too few views or views not spread over the image.
- **Coverage** of the image by the target's points, by ninths of the image.
- **A verdict**: the list of what limits this calibration, in words.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import DegenerateDataError
from ..geometry.camera_model import distort_normalized
from .lens_models import LensModel, MonoFit, fit_camera

__all__ = [
    "SPLIT_HALF_LIMIT_PX",
    "SPLIT_HALF_RATIO",
    "CameraDiagnostics",
    "diagnose",
    "intrinsics_covariance",
    "projection_uncertainty_px",
    "split_half",
]

_DIST_INDEX = {name: i for i, name in enumerate(
    ("k1", "k2", "p1", "p2", "k3", "k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y")
)}  # fmt: skip
#: The calibration is flagged when the error the halves imply for it (half their RMS
#: difference over the image: each half has about sqrt(2) times the uncertainty of all the
#: views together, and the difference of two halves sqrt(2) times that of one) exceeds this, px.
SPLIT_HALF_LIMIT_PX = 0.2
#: ... or by more than this many times what their uncertainties predict.
SPLIT_HALF_RATIO = 3.0
#: Grid of the uncertainty map and of the split-half comparison, (columns, rows).
GRID = (16, 12)


def _free_columns(model: LensModel) -> list[int]:
    """Columns of cv2.projectPoints' Jacobian for the free intrinsics (after the 6 pose ones)."""
    return [6, 7, 8, 9] + [10 + _DIST_INDEX[t] for t in model.terms]


def intrinsics_covariance(
    fit: MonoFit, object_points: Sequence[FloatArray], image_points: Sequence[FloatArray]
) -> FloatArray:
    """Covariance of the free intrinsics (fx, fy, cx, cy, then the model's terms in order).

    Parameters
    ----------
    fit : MonoFit
    object_points, image_points
        The views the fit was made from.

    Returns
    -------
    cov : (4 + n_free, 4 + n_free) float
    """
    cols = _free_columns(fit.model)
    p = len(cols)
    A = np.zeros((p, p))
    ssr, n_obs = 0.0, 0
    for obj, q, rvec, tvec in zip(object_points, image_points, fit.rvecs, fit.tvecs, strict=True):
        o = np.asarray(obj, dtype=np.float64)
        proj, jac = cv2.projectPoints(o, rvec, tvec, fit.K, fit.dist)
        J = np.asarray(jac, dtype=np.float64)
        Ji, Jp = J[:, cols], J[:, :6]
        C = Jp.T @ Jp
        B = Ji.T @ Jp
        A += Ji.T @ Ji - B @ np.linalg.solve(C, B.T)
        ssr += float(np.sum((proj.reshape(-1, 2) - np.asarray(q, dtype=np.float64)) ** 2))
        n_obs += 2 * len(o)
    dof = max(n_obs - p - 6 * len(object_points), 1)
    # Columns scaled to a unit diagonal first: the raw matrix spans many orders of magnitude
    # (focal lengths in px against distortion terms), which a plain inverse would truncate.
    d = np.sqrt(np.clip(np.diag(A), 1e-300, None))
    scaled = A / np.outer(d, d)
    if np.linalg.cond(scaled) > 1e13:
        raise DegenerateDataError(
            f"the intrinsics of lens model {fit.model.name} are not determined by these "
            f"{len(object_points)} views (information matrix singular)"
        )
    out: FloatArray = (ssr / dof) * np.linalg.inv(scaled) / np.outer(d, d)
    return out


def _grid(size: tuple[int, int]) -> FloatArray:
    w, h = size
    gx, gy = np.meshgrid(np.linspace(0, w - 1, GRID[0]), np.linspace(0, h - 1, GRID[1]))
    return np.column_stack([gx.ravel(), gy.ravel()])


def _rays(q: FloatArray, K: FloatArray, dist: FloatArray) -> FloatArray:
    xy = cv2.undistortPoints(q.reshape(-1, 1, 2), K, dist).reshape(-1, 2)
    return np.column_stack([xy, np.ones(len(xy))])


def _valid(q: FloatArray, K: FloatArray, dist: FloatArray) -> NDArray[np.bool_]:
    """Pixels whose ray the lens model gives unambiguously: the undistortion reproduces the
    pixel, and the distortion is still one-to-one there (a strong radial model folds back
    beyond some radius, often inside the image's corners)."""
    rays = _rays(q, K, dist)
    back, _ = cv2.projectPoints(rays, np.zeros(3), np.zeros(3), K, dist)
    _, jac = distort_normalized(rays[:, :2], np.asarray(dist, dtype=np.float64))
    det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
    out: NDArray[np.bool_] = (np.linalg.norm(back.reshape(-1, 2) - q, axis=1) < 0.01) & (det > 0)
    return out


def _projection_jacobians(
    rays: FloatArray, K: FloatArray, dist: FloatArray, model: LensModel
) -> tuple[FloatArray, FloatArray]:
    """d q / d intrinsics (2M, P) and d q / d small camera rotation (2M, 3) at the rays."""
    zero = np.zeros(3)
    _, jac = cv2.projectPoints(rays, zero, zero, K, dist)
    J = np.asarray(jac, dtype=np.float64)
    G = J[:, _free_columns(model)]
    dq_dv = J[:, 3:6]  # d q / d translation = d q / d the camera-frame point
    H = np.empty((len(J), 3))
    for m, v in enumerate(rays):
        skew = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
        H[2 * m : 2 * m + 2] = dq_dv[2 * m : 2 * m + 2] @ (-skew)
    return G, H


def _point_covariances(
    cov: FloatArray, K: FloatArray, dist: FloatArray, model: LensModel, q: FloatArray
) -> FloatArray:
    """(M, 2, 2) projection covariance at pixels q, the best-fitting rotation removed."""
    G, H = _projection_jacobians(_rays(q, K, dist), K, dist, model)
    Gc: FloatArray = G - H @ np.linalg.lstsq(H, G, rcond=None)[0]
    blocks = Gc.reshape(-1, 2, Gc.shape[1])
    out: FloatArray = blocks @ cov @ blocks.transpose(0, 2, 1)
    return out


def projection_uncertainty_px(fit: MonoFit, cov: FloatArray, size: tuple[int, int]) -> FloatArray:
    """1-sigma projection uncertainty (worst direction) over the image, px.

    Returns
    -------
    sigma_px : (rows, cols) float
        On a :data:`GRID` of pixels spanning the image, corners included; NaN where the lens
        model folds back (no unambiguous ray).
    """
    q = _grid(size)
    valid = _valid(q, fit.K, fit.dist)
    worst = np.full(len(q), np.nan)
    if valid.any():
        blocks = _point_covariances(cov, fit.K, fit.dist, fit.model, q[valid])
        worst[valid] = np.sqrt(np.clip(np.linalg.eigvalsh(blocks)[:, -1], 0.0, None))
    out: FloatArray = worst.reshape(GRID[1], GRID[0])
    return out


@dataclass
class SplitHalf:
    """The split-half check of one camera's intrinsics.

    Attributes
    ----------
    rms_diff_px : float
        RMS over the whole image (where both lens models are one-to-one) of how far the two
        halves project the same ray apart.
    max_diff_px : float
    observed_rms_diff_px : float
        The same over the part of the image the target's points covered.
    predicted_px : float
        The RMS difference the two halves' uncertainties predict there.
    ratio : float
        observed_rms_diff_px / predicted_px.
    flags : list of str
        What the check found wrong (empty when it passes).
    """

    rms_diff_px: float
    max_diff_px: float
    observed_rms_diff_px: float
    predicted_px: float
    ratio: float
    flags: list[str] = field(default_factory=list)


def _inside_hull(q: FloatArray, points: FloatArray) -> FloatArray:
    hull = cv2.convexHull(points.astype(np.float32))
    return np.array([cv2.pointPolygonTest(hull, (float(x), float(y)), False) >= 0 for x, y in q])


def split_half(
    object_points: Sequence[FloatArray],
    image_points: Sequence[FloatArray],
    size: tuple[int, int],
    model: LensModel,
    *,
    guess: tuple[FloatArray, FloatArray] | None = None,
) -> SplitHalf:
    """Calibrate the even and the odd views apart and compare them over the image.

    Raises
    ------
    DegenerateDataError
        Fewer than 4 views, or a half cannot be calibrated.
    """
    n = len(object_points)
    if n < 4:
        raise DegenerateDataError(f"a split-half check needs at least 4 views, got {n}")
    halves = [[i for i in range(n) if i % 2 == h] for h in (0, 1)]
    fits, covs = [], []
    for idx in halves:
        obj = [object_points[i] for i in idx]
        img = [image_points[i] for i in idx]
        fit = fit_camera(obj, img, size, model, guess=guess)
        fits.append(fit)
        covs.append(intrinsics_covariance(fit, obj, img))
    a, b = fits
    q = _grid(size)
    q = q[_valid(q, a.K, a.dist) & _valid(q, b.K, b.dist)]
    va = _rays(q, a.K, a.dist)
    vb = _rays(q, b.K, b.dist)
    seen = _inside_hull(q, np.vstack([np.asarray(p, dtype=np.float64) for p in image_points]))
    if seen.sum() < 3:
        seen = np.ones(len(q), dtype=bool)
    # Best rotation taking half A's rays onto half B's (Kabsch), over the observed region.
    ua = va[seen] / np.linalg.norm(va[seen], axis=1, keepdims=True)
    ub = vb[seen] / np.linalg.norm(vb[seen], axis=1, keepdims=True)
    u, _, vt = np.linalg.svd(ub.T @ ua)
    R = u @ np.diag([1.0, 1.0, np.linalg.det(u @ vt)]) @ vt
    qb, _ = cv2.projectPoints(va @ R.T, np.zeros(3), np.zeros(3), b.K, b.dist)
    diff = np.linalg.norm(qb.reshape(-1, 2) - q, axis=1)
    pred = sum(
        np.trace(_point_covariances(c, f.K, f.dist, model, q[seen]), axis1=1, axis2=2)
        for f, c in zip(fits, covs, strict=True)
    )
    rms = float(np.sqrt(np.mean(diff**2)))
    observed = float(np.sqrt(np.mean(diff[seen] ** 2)))
    predicted = float(np.sqrt(np.mean(pred)))
    ratio = observed / predicted if predicted > 0 else float("inf")
    flags = []
    if rms / 2.0 > SPLIT_HALF_LIMIT_PX:
        flags.append(
            f"too few views, or views not spread over the image: two halves of the views "
            f"disagree by {rms:.3f} px RMS over the image, which puts this calibration about "
            f"{rms / 2:.2f} px off (more than {SPLIT_HALF_LIMIT_PX:g})"
        )
    if ratio > SPLIT_HALF_RATIO:
        flags.append(
            f"lens model or detection: where the target was seen, two halves of the views "
            f"disagree {ratio:.1f} times more than their uncertainty predicts "
            f"({observed:.3f} px against {predicted:.3f})"
        )
    return SplitHalf(rms, float(diff.max()), observed, predicted, ratio, flags)


_NINTHS = ("top-left", "top", "top-right", "left", "centre", "right",
           "bottom-left", "bottom", "bottom-right")  # fmt: skip


def coverage(image_points: Sequence[FloatArray], size: tuple[int, int]) -> dict[str, int]:
    """Number of target points seen in each ninth of the image, by name."""
    w, h = size
    q = np.vstack([np.asarray(p, dtype=np.float64).reshape(-1, 2) for p in image_points])
    col = np.clip((q[:, 0] * 3 // w).astype(int), 0, 2)
    row = np.clip((q[:, 1] * 3 // h).astype(int), 0, 2)
    counts = np.bincount(row * 3 + col, minlength=9)
    return {name: int(c) for name, c in zip(_NINTHS, counts, strict=True)}


@dataclass
class CameraDiagnostics:
    """Everything :func:`diagnose` finds about one camera's calibration.

    Attributes
    ----------
    std_intrinsics : dict name -> float
        1-sigma of each free intrinsic (fx, fy, cx, cy in px, distortion terms unitless).
    uncertainty_map_px : (rows, cols) float
        :func:`projection_uncertainty_px`.
    split_half : SplitHalf or None
        None when it could not be made, with the reason in ``verdict``.
    coverage : dict ninth -> count
    verdict : list of str
        What limits this calibration; one line saying so when nothing was found.
    """

    std_intrinsics: dict[str, float]
    uncertainty_map_px: FloatArray
    split_half: SplitHalf | None
    coverage: dict[str, int]
    verdict: list[str]

    @property
    def uncertainty_px(self) -> dict[str, float]:
        """Projection uncertainty at the image centre, worst corner and worst anywhere, px."""
        m = self.uncertainty_map_px
        rows, cols = m.shape
        # The corners of the map, or the nearest points inside where the lens folds back.
        corners = []
        for r0, c0 in ((0, 0), (0, cols - 1), (rows - 1, 0), (rows - 1, cols - 1)):
            rr, cc = np.nonzero(np.isfinite(m))
            if len(rr):
                k = int(np.argmin((rr - r0) ** 2 + (cc - c0) ** 2))
                corners.append(float(m[rr[k], cc[k]]))
        return {
            "centre": float(m[rows // 2, cols // 2]),
            "corners": max(corners, default=float("nan")),
            "max": float(np.nanmax(m)) if np.isfinite(m).any() else float("nan"),
        }


def diagnose(
    fit: MonoFit,
    object_points: Sequence[FloatArray],
    image_points: Sequence[FloatArray],
    size: tuple[int, int],
    *,
    richest_offered: bool = False,
) -> CameraDiagnostics:
    """Diagnose one camera's calibration.

    Parameters
    ----------
    fit : MonoFit
        The calibration (its chosen lens model).
    object_points, image_points, size
        The views it was made from.
    richest_offered : bool
        The lens model is the richest that was offered: the lens may need more.
    """
    names = ["fx", "fy", "cx", "cy", *fit.model.terms]
    verdict: list[str] = []
    try:
        cov = intrinsics_covariance(fit, object_points, image_points)
        std = {n: float(np.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}
        umap = projection_uncertainty_px(fit, cov, size)
    except DegenerateDataError as exc:
        verdict.append(f"too few or too similar views: {exc}")
        std = dict.fromkeys(names, float("nan"))
        umap = np.full((GRID[1], GRID[0]), np.nan)
    cover = coverage(image_points, size)
    empty = [n for n in ("top-left", "top-right", "bottom-left", "bottom-right") if not cover[n]]
    if empty:
        verdict.append(
            "too few views near the corners: no target point in the "
            + ", ".join(empty)
            + (" ninths" if len(empty) > 1 else " ninth")
            + " of the image"
        )
    half: SplitHalf | None = None
    try:
        half = split_half(object_points, image_points, size, fit.model, guess=(fit.K, fit.dist))
        verdict += half.flags
    except DegenerateDataError as exc:
        verdict.append(f"too few views to check: {exc}")
    if richest_offered:
        verdict.append(
            f"lens model: {fit.model.name} was the richest model offered and the best; the "
            "lens may need more terms"
        )
    if not verdict:
        worst = float(np.nanmax(umap))
        agree = f", two halves of the views agree within {half.rms_diff_px:.3f} px" if half else ""
        verdict.append(
            f"no limit found: projection uncertainty at most {worst:.3f} px over the image{agree}"
        )
    return CameraDiagnostics(std, umap, half, cover, verdict)
