"""The model fit of a tool's tip: its outline's edges to sub-pixel precision, the rounded end.

Near its tip a tool is a taper: two straight edges meeting at a vertex, rounded off by its
end (a needle's sphere, a jaw's rounded corner, a pipette's opening, an ellipse in the image
when seen at an angle). The fit lays this outline over a window around the coarse tip:

- the outline is the tip point ``c`` (the end's centre), the axis's angle, the half-angle
  ``beta`` between the edges and the end's radius ``rho`` across the axis; the end is an
  ellipse whose length along the axis is ``k rho`` (``k = 1`` for a sphere; a pipette's ring
  and a jaw's plate are foreshortened, by ``k`` that the taper's true angle tells when the
  spec gives it) and the edges touch it, so the vertex is ``rho sqrt(k^2 + cot^2 beta)``
  ahead of ``c``;
- each pixel's coverage by the outline is blurred by a Gaussian whose sigma is the focus's
  blur and a defocus that grows (or falls) linearly along the axis, added in quadrature (a
  tool held at an angle leaves the focal plane); behind the end the taper is a band across
  the axis, blurred across by the sigma of its own distance, in closed form;
- the image is a plane (uneven illumination) plus the blurred coverage times the tool's
  contrast, plus for glass a term that darkens towards the outline as the square of the
  distance from the axis (its dark walls around a lighter lumen): these linear coefficients
  are solved for every trial outline (variable projection), the outline's parameters by
  Levenberg-Marquardt from the best few of a coarse grid of tips and angles, then again from
  the lowest point of a scan along the axis;
- the tip point's covariance is the fit's: ``(J^T J)^-1`` times the residual variance.

The apex reported is the tip point, not the vertex: the meeting point of the edges,
corrected for the rounded end.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import OptimizeResult, least_squares
from scipy.special import ndtr

from .._validation import FloatArray
from .tip_find import ToolBlob
from .tip_target import TipTarget

__all__ = ["TipFit", "fit_tip", "lowest_cost_fit", "neighbour_correlation_factor"]


def _blur_at(p: FloatArray, t: float) -> float:
    """The blur's sigma ``t`` px behind the tip: ``hypot(floor, a + g t)`` (the focus's blur
    and the defocus growing linearly along the tool), px."""
    floor = 0.3 + math.exp(float(np.clip(p[5], -8.0, 3.0)))
    return math.hypot(floor, float(p[6] + p[7] * max(t, 0.0)))


#: Radius around the first tip within which pixels are taken in parts, px.
_PATCH_PX = 8.0

#: The offsets of a pixel's 4 x 4 parts, (16, 2).
_PARTS = np.array([(ox, oy) for oy in (-0.375, -0.125, 0.125, 0.375)
                   for ox in (-0.375, -0.125, 0.125, 0.375)])  # fmt: skip

#: Starts of the outline's fit (the best of a coarse grid that differ).
_STARTS = 2


def _pdf(z: FloatArray) -> FloatArray:
    """The standard normal density."""
    out: FloatArray = np.exp(-0.5 * z * z) / math.sqrt(2.0 * math.pi)
    return out


@dataclass(frozen=True)
class TipFit:
    """The fitted outline (whole-image pixels)."""

    apex_px: FloatArray  # (2,) the tip point
    cov_px: FloatArray  # (2, 2)
    axis: FloatArray  # (2,) unit, tip towards shank
    vertex_px: FloatArray  # (2,)
    half_angle_rad: float
    end_radius_px: float
    blur_px: float  # sigma at the tip
    contrast: float  # darkness of the tool against the background
    rms: float  # residual, grey levels
    noise: float  # the image's noise estimate, grey levels


def _end_ratio(target: TipTarget, beta: float) -> float:
    """k: the end's length along the axis over its width, from the kind and the taper."""
    alpha = target.half_angle_rad
    if target.kind == "needle":
        return 1.0
    known = math.isfinite(alpha) and alpha > 0
    if target.kind == "jaw":
        return float(np.clip(math.tan(alpha) / math.tan(beta), 0.05, 1.0)) if known else 1.0
    if target.kind == "pipette":
        if not known:
            return 0.3
        ratio = min(math.sin(alpha) / max(math.sin(beta), 1e-9), 1.0)
        return float(np.clip(math.sqrt(1.0 - ratio * ratio), 0.05, 1.0))
    return 1.0


class _Model:
    """The outline's image over a window, for a parameter vector
    ``(cx, cy, angle, beta, log rho, log (floor - 0.3), a, g)``: the blur's sigma at ``t`` px
    behind the tip is ``hypot(floor, a + g t)`` (:func:`_blur_at`)."""

    def __init__(self, gray: NDArray[np.float32], box: tuple[int, int, int, int],
                 target: TipTarget, pad: int, tip: FloatArray) -> None:  # fmt: skip
        x0, y0, x1, y1 = box
        self.box, self.pad, self.target = box, pad, target
        self.image = gray[y0:y1, x0:x1].astype(np.float64).ravel()
        h, w = y1 - y0, x1 - x0
        ys, xs = np.mgrid[-pad : h + pad, -pad : w + pad].astype(np.float64)
        self.X, self.Y = xs, ys
        self.shape = (h, w)
        cx, cy = (w - 1) / 2, (h - 1) / 2
        gx, gy = xs[pad:-pad, pad:-pad].ravel() - cx, ys[pad:-pad, pad:-pad].ravel() - cy
        self.plane = np.column_stack([np.ones_like(gx), gx / max(w, 1), gy / max(h, 1)])
        self.glass = target.kind in ("pipette", "any")
        self.reach = float(max(h, w))
        # The pixels around the first tip, each taken in 4 x 4 parts (a fixed set, so that the
        # cost is smooth in the tip's position).
        near = np.hypot(xs - (tip[0] - x0), ys - (tip[1] - y0)) < _PATCH_PX
        self.patch = np.nonzero(near)

    def geometry(self, p: FloatArray) -> tuple[float, float, float, float, float]:
        """(beta, rho, k, D, tc) of a parameter vector."""
        beta = float(np.clip(p[3], 0.004, 1.3))
        rho = float(math.exp(np.clip(p[4], -8.0, 4.0)))
        k = _end_ratio(self.target, beta)
        sb, cb = math.sin(beta), math.cos(beta)
        D = rho * math.sqrt(k * k + (cb / sb) ** 2)
        tc = -k * k * rho * sb / math.sqrt(k * k * sb * sb + cb * cb)
        return beta, rho, k, D, tc

    def bases(self, p: FloatArray) -> NDArray[np.float64]:
        """The design matrix: the plane and the blurred outline (and wall band), (N, 4 or 5)."""
        beta, rho, k, D, tc = self.geometry(p)
        c, s = math.cos(p[2]), math.sin(p[2])
        dx, dy = self.X - p[0], self.Y - p[1]
        t = dx * c + dy * s
        x = np.abs(dy * c - dx * s)
        _sb, cb = math.sin(beta), math.cos(beta)
        cover, taper, end, re = _cover(t, x, beta, rho, k, D, tc, 1.0)
        # Around the end, where the outline bends within a pixel, each pixel is 4 x 4 parts.
        iy, ix = self.patch
        if iy.size:
            ddx = dx[iy, ix][:, None] + _PARTS[:, 0]
            ddy = dy[iy, ix][:, None] + _PARTS[:, 1]
            tt, xx = ddx * c + ddy * s, np.abs(ddy * c - ddx * s)
            cover[iy, ix] = _cover(tt, xx, beta, rho, k, D, tc, 0.25)[0].mean(axis=1)
        floor = 0.3 + math.exp(np.clip(p[5], -8.0, 3.0))
        s0 = _blur_at(p, 0.0)
        layers = [cover]
        if self.glass:
            half = np.maximum((t + D) * math.tan(beta), 1e-3)
            xi = np.where(taper <= end, x / half, re)
            layers.append(cover * np.minimum(xi, 1.0) ** 2)
        pad = self.pad
        inner = (slice(pad, -pad), slice(pad, -pad))
        # Behind the end the taper is a band across the axis whose blur changes along it:
        # blurred across only, by the sigma of its own distance (and the pixel's width).
        ti, xi_ = t[inner], x[inner]
        sigma = np.sqrt(floor**2 + (p[6] + p[7] * np.maximum(ti, 0.0)) ** 2 + 1 / 12)
        sigma /= cb
        hw = np.maximum((ti + D) * math.tan(beta), 0.0)
        a, b = (-hw - xi_) / sigma, (hw - xi_) / sigma
        inside = ndtr(b) - ndtr(a)
        strips = [inside]
        if self.glass:  # the band's (u / hw)^2 weighted by the Gaussian, in closed form
            pa, pb = _pdf(a), _pdf(b)
            second = xi_**2 * inside + 2 * xi_ * sigma * (pa - pb)
            second += sigma**2 * (inside + a * pa - b * pb)
            strips.append(second / np.maximum(hw, 1e-3) ** 2)
        # ... and near the end, where it is short, its whole outline blurred by the tip's blur.
        ramp = np.clip((ti - tc - 3.0 * s0 - 1.0) / (3.0 * s0 + 3.0), 0.0, 1.0)
        cols = [self.plane]
        for layer, strip in zip(layers, strips, strict=True):
            near_end = np.asarray(cv2.GaussianBlur(layer, (0, 0), s0)[inner], dtype=np.float64)
            cols.append((near_end * (1.0 - ramp) + strip * ramp).reshape(-1, 1))
        return np.hstack(cols)

    def solve(self, p: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(residuals, linear coefficients) of a parameter vector."""
        A = self.bases(p)
        coef = np.asarray(np.linalg.lstsq(A, self.image, rcond=None)[0], dtype=np.float64)
        out: FloatArray = self.image - A @ coef
        return out, coef

    def residuals(self, p: FloatArray) -> FloatArray:
        """The residuals of a parameter vector (the linear coefficients solved for)."""
        return self.solve(p)[0]


def _cover(
    t: FloatArray,
    x: FloatArray,
    beta: float,
    rho: float,
    k: float,
    D: float,
    tc: float,
    width: float,
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """The outline's coverage of squares of side ``width`` centred at (t along the axis from the
    tip point, x = |across|), and the taper's and the end's signed distances and the end's
    normalised radius."""
    sb, cb = math.sin(beta), math.cos(beta)
    near = (t + D) * sb
    h = 0.5 * width
    # Each edge's signed distance; a square's share of the band between them counts both, so
    # that a taper narrower than the square covers it in proportion to its width.
    between = np.clip((h - (x * cb - near)) / width, 0.0, 1.0)
    between += np.clip((h - (-x * cb - near)) / width, 0.0, 1.0)
    taper_cover = np.clip(between - 1.0, 0.0, 1.0) * np.clip((h - (tc - t)) / width, 0.0, 1.0)
    taper = np.maximum(x * cb - near, tc - t)
    kr = max(k * rho, 1e-3)
    re = np.sqrt((t / kr) ** 2 + (x / rho) ** 2)
    # The distance from the ellipse to first order, (re - 1) / |grad re|: right for a thin one.
    slope = np.sqrt((t / kr**2) ** 2 + (x / rho**2) ** 2) / np.maximum(re, 1e-12)
    end = (re - 1.0) / np.maximum(slope, 1.0 / max(kr, rho))
    end_cover = np.clip((h - end) / width, 0.0, 1.0)
    if k < 1.0 and kr < h:
        # An end thinner along the axis than the square (a pipette's ring seen nearly
        # edge-on): the square's share of a band as thick as the ellipse's chord along the
        # axis (the distance above would thicken it to the square's width).
        chord = kr * np.sqrt(np.clip(1.0 - (x / rho) ** 2, 0.0, 1.0))
        end_cover = np.clip((np.minimum(chord, t + h) - np.maximum(-chord, t - h)) / width, 0, 1)
    cover = np.maximum(taper_cover, end_cover)
    return cover, taper, end, re


def lowest_cost_fit(
    residuals: Callable[[FloatArray], FloatArray], starts: Sequence[FloatArray], **options: Any
) -> OptimizeResult | None:
    """The least-squares fit of ``residuals`` of lowest cost over the ``starts`` (each (k,)),
    with scipy's ``least_squares`` ``options``; a start the solver fails on is passed over.
    None when it fails on every start."""
    fit = None
    for start in starts:
        try:
            trial = least_squares(residuals, start, **options)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if fit is None or trial.cost < fit.cost:
            fit = trial
    return fit


def neighbour_correlation_factor(field: FloatArray) -> float:
    """How much neighbouring residuals agree, as the factor by which they inflate the variance
    of what is fitted to them: ``prod (1 + r) / (1 - r)`` over the rows and the columns, ``r``
    the correlation of neighbours (1 for white noise; a model's own mismatch is smooth).

    ``field`` (H, W) holds the residuals at their pixels and NaN elsewhere.
    """
    factor = 1.0
    for a, b in ((field[:, 1:], field[:, :-1]), (field[1:, :], field[:-1, :])):
        ok = np.isfinite(a) & np.isfinite(b)
        if ok.sum() < 10:
            continue
        x, y = a[ok], b[ok]
        r = float(np.clip(np.mean(x * y) / max(math.sqrt(np.mean(x * x) * np.mean(y * y)), 1e-12),
                          0.0, 0.9))  # fmt: skip
        factor *= (1.0 + r) / (1.0 - r)
    return factor


def _noise(gray: NDArray[np.float32]) -> float:
    """The image's pixel noise, from the differences of neighbours (robust), grey levels."""
    d = np.diff(gray.astype(np.float64), axis=1)
    return float(1.4826 * np.median(np.abs(d - np.median(d))) / math.sqrt(2.0))


def fit_tip(
    gray: NDArray[np.float32], blob: ToolBlob, target: TipTarget, *, half_window_px: int = 24
) -> TipFit | str:
    """Fit the tip's outline around the coarse tip of ``blob`` (see the module docstring)."""
    h, w = gray.shape
    axis = blob.axis
    angle = math.atan2(axis[1], axis[0])
    beta0 = float(np.clip(blob.half_angle_rad, 0.01, 1.0))
    blur = 1.5
    p = np.array([0.0, 0.0, angle, beta0, 0.0, math.log(blur - 0.3), 0.3, 0.01])
    tip = blob.tip_px.copy()
    fit = None
    for attempt in range(2):
        r = half_window_px if attempt == 0 else int(min(3 * half_window_px, 6 * blur + 16))
        centre = tip + axis * (0.5 * r)
        x0, y0 = max(round(centre[0]) - r, 0), max(round(centre[1]) - r, 0)
        x1, y1 = min(round(centre[0]) + r + 1, w), min(round(centre[1]) + r + 1, h)
        if x1 - x0 < 12 or y1 - y0 < 12:
            return "the tip is at the edge of the field"
        pad = int(3 * max(blur, 2.0)) + 6
        model = _Model(gray, (x0, y0, x1, y1), target, pad, tip)
        p[0], p[1] = tip[0] - x0, tip[1] - y0
        starts = [p]
        if attempt == 0:  # the best few of a grid of tips along the axis and taper angles
            grid = []
            for beta in beta0 * np.array([0.5, 0.7, 1.0, 1.4]):
                for sft in np.arange(-6.0, 6.5, 1.5):
                    q = p.copy()
                    q[:2] += axis * sft
                    q[3] = beta
                    grid.append((float(np.sum(model.residuals(q) ** 2)), sft, q))
            grid.sort(key=lambda g: g[0])
            starts = [grid[0][2]]
            for *_, q in grid[1:]:
                if len(starts) == _STARTS:
                    break
                if all(abs(q[3] - o[3]) > 0.1 * beta0 or np.hypot(*(q[:2] - o[:2])) > 2.0
                       for o in starts):  # fmt: skip
                    starts.append(q)
        fit = lowest_cost_fit(model.residuals, starts, method="lm", x_scale="jac",
                              diff_step=1e-4, max_nfev=400)  # fmt: skip
        if fit is None:
            return "the model fit failed on this image"
        # The tip's place along the axis may lie in a neighbouring dip of the cost: scan
        # along the fitted axis and fit again from the lowest point when it is lower.
        u = np.array([math.cos(fit.x[2]), math.sin(fit.x[2])])
        scan = []
        for sft in np.arange(-3.0, 3.01, 0.5):
            q = fit.x.copy()
            q[:2] += u * sft
            scan.append((float(np.sum(model.residuals(q) ** 2)), sft))
        cost, sft = min(scan)
        if sft != 0.0 and cost < 2 * fit.cost:
            q = fit.x.copy()
            q[:2] += u * sft
            trial = lowest_cost_fit(model.residuals, [q], method="lm", x_scale="jac",
                                    diff_step=1e-4, max_nfev=400)  # fmt: skip
            fit = trial if trial is not None and trial.cost < fit.cost else fit
        p = fit.x
        blur = _blur_at(p, 0.0)
        tip = np.array([p[0] + x0, p[1] + y0])
        if 6 * blur + 16 <= 1.5 * half_window_px:
            break
    assert fit is not None
    resid, coef = model.solve(p)
    n, m = resid.size, p.size + coef.size
    rss = float(resid @ resid)
    J = fit.jac
    cov = np.linalg.pinv(J.T @ J) * rss / max(n - m, 1)
    if not np.all(np.isfinite(cov[:2, :2])) or min(np.linalg.eigvalsh(cov[:2, :2])) <= 0:
        return "the model fit is degenerate (the tool's outline is not seen)"
    beta, rho, _, D, _ = model.geometry(p)
    u = np.array([math.cos(p[2]), math.sin(p[2])])
    level = float(coef[0])
    contrast = -float(coef[3]) / max(abs(level), 1e-9)
    if model.glass:  # the darkest the glass's profile gets, edge or middle
        contrast = -float(min(coef[3], coef[3] + coef[4])) / max(abs(level), 1e-9)
    return TipFit(
        apex_px=tip, cov_px=cov[:2, :2], axis=u, vertex_px=tip - u * D,
        half_angle_rad=beta, end_radius_px=rho, blur_px=max(blur, 0.3), contrast=contrast,
        rms=math.sqrt(rss / n), noise=_noise(gray[y0:y1, x0:x1]),
    )  # fmt: skip
