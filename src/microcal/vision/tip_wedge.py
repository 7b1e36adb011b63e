"""A tool's taper fitted along its straight edges: the vertex where they meet, in ideal pixels.

Where a tool's end is smaller than the blur (a gripper jaw's 40 µm corner on a camera of 22
µm pixels, under a blur of 1.7 px), the end's outline cannot tell how far the tip point lies
ahead of the taper: the model fit's end (:mod:`~microcal.vision.tip_fit`) leaves the apex
some tenths of a pixel off without noise and about a pixel off in one noisy frame. The
taper's two straight edges, followed far behind the end, fix their meeting point (the
vertex, a fixed point of the tool: a jaw's plate's corner, a cone's apex) far better, and
the tip point then follows in 3D from the tool's known size
(:mod:`~microcal.vision.tip_vertex`).

The fit, in the camera's ideal (undistorted) pixels, where the edges are straight lines:

- the pixels within ``3 sigma + 3`` px of either edge, from ``5 sigma + 3`` px behind the
  end's contact with the taper (where the rounded end no longer reaches through the blur) to
  :data:`REACH_PX` behind the vertex;
- the image there is the light to second order (uneven illumination, vignetting) times one
  minus the tool's darkness times the blurred coverage of a wedge,
  ``Phi(-d_1 / s) + Phi(-d_2 / s) - 1``, ``d_k`` a pixel's signed distance from edge ``k``
  (exact for a wedge's blurred edges away from its vertex), ``s`` the blur growing linearly
  along the tool;
- the nonlinear parameters (vertex, the edges' angles, the blur and its growth) by
  Levenberg-Marquardt, the linear ones solved for at each step (variable projection); the
  vertex's and the angles' covariance is the fit's, ``(J^T J)^-1`` times the residual
  variance;
- a camera that cuts its noise at 0 (no black level: 1 % or more of the pixels at 0 and none
  below) lifts a dark tool's mean and moved the vertex by half a pixel along the axis on the
  thesis's cameras: the fit is then made again with the expected value of a pixel cut at 0,
  ``mu Phi(mu / sigma) + sigma phi(mu / sigma)``, ``sigma`` the noise of the bright pixels.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.special import ndtr

from .._validation import FloatArray
from ..geometry import AnyCamera
from .tip import TipDetection

__all__ = ["CLIPPED_SHARE", "REACH_PX", "WedgeFit", "fit_wedge"]

#: How far behind the vertex the edges are followed, px (within the image).
REACH_PX = 480.0
#: The share of the fitted pixels at 0 above which the camera is taken to clip its noise.
CLIPPED_SHARE = 0.01


@dataclass(frozen=True)
class WedgeFit:
    """The taper's edges fitted in ideal pixels.

    Attributes
    ----------
    vertex_px : (2,) float
        Where the edges meet, ideal pixels.
    axis : (2,) float
        Unit bisector of the edges, from the vertex towards the shank.
    cov : (4, 4) float
        Covariance of (vertex x, vertex y, angle of edge 1, angle of edge 2), px^2 and rad^2.
    half_angle_rad : float
        Half the angle between the edges in the image.
    blur_px : float
        The blur's sigma at the start of the edges, px.
    pixels : int
        Pixels fitted.
    edge_angles_rad : (float, float)
        The edges' directions from the vertex towards the shank, rad.
    """

    vertex_px: FloatArray
    axis: FloatArray
    cov: FloatArray
    half_angle_rad: float
    blur_px: float
    pixels: int
    edge_angles_rad: tuple[float, float] = (math.nan, math.nan)

    @property
    def edges(self) -> FloatArray:
        """The edges' unit directions from the vertex towards the shank, (2, 2): the one on
        the axis's left (``axis x edge > 0``) first; with their angles' variances
        :attr:`edge_vars` in the same order."""
        return self._ordered()[0]

    @property
    def edge_vars(self) -> FloatArray:
        """Variances of the angles of :attr:`edges`, (2,) rad^2."""
        return self._ordered()[1]

    def _ordered(self) -> tuple[FloatArray, FloatArray]:
        e = np.array([[math.cos(a), math.sin(a)] for a in self.edge_angles_rad])
        var = np.diagonal(self.cov)[2:].copy()
        if self.axis[0] * e[0, 1] - self.axis[1] * e[0, 0] < 0:
            return e[::-1].copy(), var[::-1].copy()
        return e, var

    @property
    def axis_angle_var(self) -> float:
        """Variance of the axis's angle (the mean of the edges' angles), rad^2."""
        c = self.cov[2:, 2:]
        return float(0.25 * (c[0, 0] + c[1, 1] + 2 * c[0, 1]))


class _Pixels:
    """The fitted pixels and the model of their values, for ``x`` = (the wedge's 6
    parameters, the linear model's coefficients); with ``noise`` (DN) > 0, the expected
    value of a pixel whose noise is clipped at 0."""

    def __init__(self, q: FloatArray, img: FloatArray, t_mid: float, plane: FloatArray) -> None:
        self.q, self.img, self.t_mid, self.plane = q, img, t_mid, plane
        self.noise = 0.0

    def design(self, p: FloatArray) -> FloatArray:
        """The linear model's columns: the light and the tool's darkness in proportion to
        it, (N, 2 k)."""
        cover, _ = _wedge(p[:6], self.q, self.t_mid)
        out: FloatArray = np.column_stack([self.plane, self.plane * cover[:, None]])
        return out

    def solve(self, p: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(residuals, linear coefficients) of the wedge ``p`` (6,), the noise not clipped."""
        A = self.design(p)
        coef: FloatArray = np.linalg.solve(A.T @ A, A.T @ self.img).astype(np.float64)
        return self.img - A @ coef, coef

    def residuals(self, x: FloatArray) -> FloatArray:
        """The residuals of all parameters."""
        mu = self.design(x) @ x[6:]
        if self.noise > 0:
            z = mu / self.noise
            mu = mu * ndtr(z) + self.noise * _pdf(z)
        out: FloatArray = self.img - mu
        return out

    def bright_noise(self, x: FloatArray) -> float:
        """The noise's robust sigma over the pixels whose model is in the brightest 40 %."""
        pred = self.design(x) @ x[6:]
        r = (self.img - pred)[pred > np.percentile(pred, 60)]
        return max(float(1.4826 * np.median(np.abs(r - np.median(r)))), 1e-6)


def _jacobian(f: Callable[[FloatArray], FloatArray], x: FloatArray) -> FloatArray:
    """Central differences of ``f`` at ``x``, (m, n)."""
    cols = []
    for i in range(len(x)):
        step = 1e-6 * max(abs(x[i]), 1.0)
        e = np.zeros_like(x)
        e[i] = step
        cols.append((f(x + e) - f(x - e)) / (2 * step))
    return np.column_stack(cols)


def _pdf(z: FloatArray) -> FloatArray:
    out: FloatArray = np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    return out


def _wedge(p: FloatArray, q: FloatArray, t_mid: float) -> tuple[FloatArray, FloatArray]:
    """The blurred wedge's coverage at ideal points ``q`` (N, 2) and their distance along its
    bisector from the vertex, for ``p = (vx, vy, theta1, theta2, log sigma, slope)``."""
    d = q - p[:2]
    out = np.zeros(len(q))
    bis = np.array([math.cos(p[2]) + math.cos(p[3]), math.sin(p[2]) + math.sin(p[3])])
    bis /= max(float(np.linalg.norm(bis)), 1e-12)
    t = d @ bis
    sigma = np.maximum(math.exp(p[4]) + p[5] * (t - t_mid), 0.3)
    for angle in (p[2], p[3]):
        e = np.array([math.cos(angle), math.sin(angle)])
        n = np.array([-e[1], e[0]])
        if n @ bis > 0:  # outward: away from the bisector
            n = -n
        out += ndtr(-(d @ n) / sigma)
    return out - 1.0, t


def fit_wedge(
    gray: NDArray[np.floating],
    camera: AnyCamera,
    det: TipDetection,
    *,
    end_px: float,
    reach_px: float = REACH_PX,
) -> WedgeFit | str:
    """Fit the taper's edges of the tool found by ``det`` in the whole image ``gray``.

    Parameters
    ----------
    gray : (H, W) float
        The whole image (the detection's pixels are the image's).
    camera : AnyCamera
        Its model, for the ideal pixels.
    det : TipDetection
        The model fit's detection (vertex, axis, half-angle and blur as starting values).
    end_px : float
        How far behind the vertex the rounded end reaches (its contact with the taper), px.
    reach_px : float
        How far behind the vertex the edges are followed, px.

    Returns
    -------
    WedgeFit, or the reason it failed.
    """
    if not det.found or not np.all(np.isfinite(det.vertex_px)):
        return "no vertex to start the edges' fit from"
    h, w = gray.shape
    v0, u0 = det.vertex_px, det.axis
    beta = math.radians(det.half_angle_deg)
    blur = float(np.clip(det.blur_px, 0.5, 6.0))
    band = 3.0 * blur + 3.0
    t0 = end_px + 5.0 * blur + 3.0
    ends = np.array([v0, v0 + u0 * reach_px])
    half = reach_px * math.tan(beta) + band
    x0, y0 = np.floor(ends.min(axis=0) - half).astype(int)
    x1, y1 = np.ceil(ends.max(axis=0) + half).astype(int)
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, w), min(y1, h)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return "the taper is out of the field"
    ys, xs = np.mgrid[y0:y1, x0:x1]
    pix = np.column_stack([xs.ravel(), ys.ravel()]).astype(np.float64)
    # the band around the edges, first in the image's pixels (with room for the lens's
    # bending), then in ideal pixels
    rough = _band(pix, v0, u0, beta, t0 - band, reach_px + band, 2.0 * band)
    pix = pix[rough]
    distorts = _distorts(camera)
    ideal = np.asarray(camera.undistort_px(pix), dtype=np.float64) if distorts else pix
    ends2 = np.array([v0, v0 + 20.0 * u0])
    iv = np.asarray(camera.undistort_px(ends2), dtype=np.float64) if distorts else ends2
    axis = (iv[1] - iv[0]) / np.linalg.norm(iv[1] - iv[0])
    phi = math.atan2(axis[1], axis[0])
    keep = _band(ideal, iv[0], axis, beta, t0, reach_px, band)
    if np.count_nonzero(keep) < 60:
        return "too little of the taper's edges is seen"
    q = ideal[keep]
    img = np.asarray(gray[y0:y1, x0:x1], dtype=np.float64).ravel()[rough][keep]
    t_mid = 0.5 * (t0 + reach_px)
    g = (q - q.mean(axis=0)) / reach_px
    # the light (vignetting, uneven illumination) to second order, and the tool's darkness
    # in proportion to it
    plane = np.column_stack([np.ones(len(q)), g, g * g, g[:, :1] * g[:, 1:]])

    p0 = np.array([iv[0][0], iv[0][1], phi + beta, phi - beta, math.log(blur), 0.0])
    model = _Pixels(q, img, t_mid, plane)
    try:
        fit = least_squares(lambda p: model.solve(p)[0], p0, method="lm", x_scale="jac",
                            diff_step=1e-6, max_nfev=300)  # fmt: skip
        x = np.concatenate([fit.x, model.solve(fit.x)[1]])
        # A camera that clips its noise at 0 (no black level) lifts a dark tool's mean and
        # moves its edges outwards: then the fit again with the expected value of a pixel
        # clipped at 0, the noise that of the pixels well above the dark level.
        clipped = img.min() >= 0 and np.count_nonzero(img == 0) >= CLIPPED_SHARE * len(img)
        if clipped:
            model.noise = model.bright_noise(x)
            fit = least_squares(model.residuals, x, method="lm", x_scale="jac",
                                diff_step=1e-6, max_nfev=3000, ftol=1e-12,
                                xtol=1e-12)  # fmt: skip
            x = fit.x
    except (ValueError, np.linalg.LinAlgError):
        return "the edges' fit failed"
    resid = model.residuals(x)
    J = fit.jac if clipped else _jacobian(model.residuals, x)
    coef = x[6:]
    dof = max(len(resid) - len(x), 1)
    try:
        cov = np.linalg.inv(J.T @ J) * float(resid @ resid) / dof
    except np.linalg.LinAlgError:
        return "the edges' fit is degenerate"
    if not np.all(np.isfinite(cov)) or coef[plane.shape[1]] >= 0:
        return "the edges' fit found no dark taper"
    p = x
    bis = np.array([math.cos(p[2]) + math.cos(p[3]), math.sin(p[2]) + math.sin(p[3])])
    bis /= np.linalg.norm(bis)
    half_angle = 0.5 * abs(math.remainder(p[2] - p[3], 2 * math.pi))
    if float(np.linalg.norm(p[:2] - iv[0])) > 3.0 + 2.0 * blur:
        moved = float(np.linalg.norm(p[:2] - iv[0]))
        return f"the edges' fit did not settle (its vertex moved {moved:.1f} px)"
    return WedgeFit(p[:2].copy(), bis, cov[:4, :4], half_angle, math.exp(p[4]), len(q),
                    (float(p[2]), float(p[3])))  # fmt: skip


def _band(
    q: FloatArray, v: FloatArray, u: FloatArray, beta: float, t0: float, t1: float, band: float
) -> NDArray[np.bool_]:
    """Which points (N, 2) lie within ``band`` of either edge of the wedge at ``v`` (axis
    ``u``, half-angle ``beta``), between ``t0`` and ``t1`` along the axis."""
    d = q - v
    t = d @ u
    x = d @ np.array([-u[1], u[0]])
    near_edge = np.abs(np.abs(x) * math.cos(beta) - t * math.sin(beta))
    out: NDArray[np.bool_] = (t >= t0) & (t <= t1) & (near_edge <= band)
    return out


def _distorts(camera: AnyCamera) -> bool:
    return bool(getattr(camera, "has_distortion", True))
