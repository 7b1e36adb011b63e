"""Estimation of an affine (telecentric) camera from 3D-2D correspondences, and its uncertainty.

Two steps, as for the pinhole camera (DLT, then refinement):

- :func:`estimate_affine_matrix`: the linear estimate. An affine camera is ``q = M p + m``
  with M 2x3: eight unknowns, linear in the pixels, solved by least squares on points
  centred on their centroid and scaled to unit RMS (the affine analogue of Hartley's
  normalisation; the centroid maps to the centroid, which gives m). Needs four non-coplanar
  points at least.
- :func:`refine_affine_camera`: the non-linear fit with lens distortion. The parameters are
  a small rotation about the linear estimate's R, the translation across the axis, the
  magnifications and skew and the free distortion terms; Levenberg-Marquardt on the pixel
  residuals. The principal point stays where the start has it (the image centre): without
  distortion it is one with the translation, and with it a shift of the distortion centre
  is, to first order, the tangential terms p1, p2 (``r^2 d + 2 (x . d) x``), so the two
  cannot both be fitted (tried: 50 px of scatter in the centre over noise draws). The
  covariance of the parameters is ``s^2 (J^T J)^-1`` (s^2 the residual variance, J with
  scaled columns), and :func:`projection_std_px` propagates it to the projection of any
  point.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.spatial.transform import Rotation

from .._validation import FloatArray, as_rows
from ..errors import DegenerateDataError, InputError
from .affine_camera import AffineCamera

__all__ = [
    "AFFINE_DIST_TERMS",
    "AffineFit",
    "estimate_affine_matrix",
    "projection_std_px",
    "refine_affine_camera",
]

#: Distortion terms a refinement may free, by their index in OpenCV's order.
AFFINE_DIST_TERMS = {"k1": 0, "k2": 1, "p1": 2, "p2": 3, "k3": 4}

#: Below this ratio of the centred points' smallest to largest singular value the points are
#: coplanar for the purpose of the linear estimate.
_COPLANAR = 1e-6


def _points(p_um: ArrayLike, q_px: ArrayLike) -> tuple[FloatArray, FloatArray]:
    p = as_rows(p_um, "p_um", 3)
    q = as_rows(q_px, "q_px", 2)
    if p.shape[0] != q.shape[0]:
        raise InputError(
            f"p_um and q_px: expected the same number of points, got {p.shape[0]} and {q.shape[0]}"
        )
    return p, q


def estimate_affine_matrix(p_um: ArrayLike, q_px: ArrayLike) -> FloatArray:
    """Linear least-squares estimate of an affine camera's projection matrix.

    Parameters
    ----------
    p_um : (N, 3) float
        World points, µm; N >= 4, not coplanar.
    q_px : (N, 2) float
        Their (undistorted) pixels.

    Returns
    -------
    P : (3, 4) float
        ``[[M, m], [0, 0, 0, 1]]``: the least-squares affine camera (minimises the pixel
        residuals, the maximum-likelihood estimate for isotropic pixel noise).

    Raises
    ------
    DegenerateDataError
        Fewer than four points, or points (nearly) in one plane or on one line.
    """
    p, q = _points(p_um, q_px)
    if p.shape[0] < 4:
        raise DegenerateDataError(f"affine camera: expected at least 4 points, got {p.shape[0]}")
    p0 = p.mean(axis=0)
    q0 = q.mean(axis=0)
    pc = p - p0
    scale = float(np.sqrt(np.mean(np.sum(pc**2, axis=1))))
    if not scale > 0:
        raise DegenerateDataError("affine camera: the points all coincide")
    pn = pc / scale
    sv = np.linalg.svd(pn, compute_uv=False)
    if sv[2] < _COPLANAR * sv[0]:
        raise DegenerateDataError(
            "affine camera: the points lie in one plane; points at two depths at least are "
            "needed (move the target along its normal)"
        )
    Mn, *_ = np.linalg.lstsq(pn, q - q0, rcond=None)  # (3, 2): q - q0 = pn Mn
    M = Mn.T / scale
    P = np.zeros((3, 4))
    P[:2, :3] = M
    P[:2, 3] = q0 - M @ p0
    P[2, 3] = 1.0
    return P


@dataclass
class AffineFit:
    """A refined affine camera and the figures of its fit.

    Attributes
    ----------
    camera : AffineCamera
    rms_px : float
        RMS of the residual vectors, px.
    names : list of str
        The free parameters, in the order of ``cov``.
    cov : (k, k) float
        Covariance of the free parameters (``s^2 (J^T J)^-1``).
    std : dict of str -> float
        Standard deviation of each free parameter (magnification in px/µm, principal point
        in px, distortion as its coefficient).
    params : (k,) float
        The free parameters' values.
    start : AffineCamera
        The camera the parameters are relative to.
    dist_terms : tuple of str
        The distortion terms fitted.
    """

    camera: AffineCamera
    rms_px: float
    names: list[str]
    cov: FloatArray
    std: dict[str, float]
    params: FloatArray
    start: AffineCamera
    dist_terms: tuple[str, ...]

    def camera_at(self, params: FloatArray) -> AffineCamera:
        """The camera of other values of the free parameters (for derivatives)."""
        return _unpack(params, self.start, self.dist_terms)


def _unpack(x: FloatArray, start: AffineCamera, free: Sequence[str]) -> AffineCamera:
    R = Rotation.from_rotvec(x[:3]).as_matrix() @ start.R
    t = np.array([x[3], x[4], start.t_um[2]])
    K = np.array([[x[5], x[7], start.K[0, 2]], [0.0, x[6], start.K[1, 2]], [0.0, 0.0, 1.0]])
    i = 8
    dist = np.array(start.dist[:5] if len(start.dist) >= 5 else np.zeros(5), dtype=np.float64)
    dist = dist.copy()
    for name in free:
        dist[AFFINE_DIST_TERMS[name]] = x[i]
        i += 1
    return AffineCamera(K, dist, R, t, start.image_size_px, start.name)


def refine_affine_camera(
    p_um: ArrayLike,
    q_px: ArrayLike,
    start: AffineCamera,
    dist_terms: Sequence[str] = ("k1",),
) -> AffineFit:
    """Non-linear least-squares fit of an affine camera with lens distortion.

    Parameters
    ----------
    p_um : (N, 3) float
        World points, µm.
    q_px : (N, 2) float
        Their observed pixels (lens distortion included).
    start : AffineCamera
        The starting camera (from :func:`estimate_affine_matrix`); its principal point is
        kept.
    dist_terms : sequence of str
        The distortion terms to fit, of :data:`AFFINE_DIST_TERMS`; the others stay at the
        start's values (zero). Empty: a distortion-free affine camera.

    Returns
    -------
    AffineFit

    Raises
    ------
    InputError
        An unknown distortion term.
    DegenerateDataError
        Fewer points than twice the free parameters.
    """
    p, q = _points(p_um, q_px)
    free = list(dist_terms)
    unknown = [t for t in free if t not in AFFINE_DIST_TERMS]
    if unknown:
        raise InputError(
            f"dist_terms: expected some of {', '.join(AFFINE_DIST_TERMS)}, got {unknown}"
        )
    d0 = np.asarray(start.dist, dtype=np.float64)
    x0 = np.concatenate([
        np.zeros(3), start.t_um[:2], [start.K[0, 0], start.K[1, 1], start.K[0, 1]],
        [d0[AFFINE_DIST_TERMS[t]] for t in free],
    ])  # fmt: skip
    names = ["rot_x", "rot_y", "rot_z", "t_x_um", "t_y_um", "mx_px_per_um", "my_px_per_um",
             "skew", *free]  # fmt: skip
    if 2 * p.shape[0] < 2 * len(x0):
        raise DegenerateDataError(
            f"affine camera: {p.shape[0]} points for {len(x0)} parameters; more views are needed"
        )

    def residuals(x: FloatArray) -> FloatArray:
        cam = _unpack(x, start, free)
        return np.asarray((cam.project(p) - q).ravel(), dtype=np.float64)

    sol = least_squares(residuals, x0, method="lm", x_scale="jac", xtol=1e-12, ftol=1e-12)
    cam = _unpack(sol.x, start, free)
    r = sol.fun
    dof = max(r.size - len(x0), 1)
    s2 = float(r @ r) / dof
    J = sol.jac
    norms = np.linalg.norm(J, axis=0)
    norms[norms == 0] = 1.0
    Js = J / norms  # columns scaled: the parameters' units differ by orders of magnitude
    cov = s2 * np.linalg.pinv(Js.T @ Js) / np.outer(norms, norms)
    std = {n: float(np.sqrt(max(cov[i, i], 0.0))) for i, n in enumerate(names)}
    rms = float(np.sqrt(np.mean(np.sum(r.reshape(-1, 2) ** 2, axis=1))))
    return AffineFit(cam, rms, names, cov, std, sol.x, start, tuple(free))


def projection_std_px(fit: AffineFit, p_um: ArrayLike) -> FloatArray:
    """Standard deviation per image axis of the fitted camera's projection of points, from
    the covariance of its parameters (first order, derivatives by central differences).

    Parameters
    ----------
    fit : AffineFit
    p_um : (N, 3) float
        Points in {G}, µm.

    Returns
    -------
    std_px : (N,) float
        ``sqrt(trace(J C J^T) / 2)`` per point: the 1-sigma error per axis, px.
    """
    p = as_rows(p_um, "p_um", 3)
    x = fit.params
    sd = np.sqrt(np.maximum(np.diag(fit.cov), 0.0))
    J = np.empty((p.shape[0], 2, len(x)))
    for i in range(len(x)):
        h = max(sd[i], 1e-12) * 1e-2
        xp, xm = x.copy(), x.copy()
        xp[i] += h
        xm[i] -= h
        J[:, :, i] = (fit.camera_at(xp).project(p) - fit.camera_at(xm).project(p)) / (2 * h)
    var = np.einsum("nik,kl,nil->n", J, fit.cov, J)
    return np.asarray(np.sqrt(np.maximum(var, 0.0) / 2.0), dtype=np.float64)
