"""The tip fitted by the image of a tapered tool: analysis by synthesis near its end.

A small forward model of the projected tool is drawn over a window around the coarse tip and
fitted to its pixels by least squares. Being the image of the whole outline (not its edges
found one by one), it has no bias along the axis from the sub-pixel narrowing of the taper,
which is what an edge-based fit suffers when the tool is a pixel or two wide.

The model, from the geometry of a taper seen by a telecentric (or nearly) microscope:

- **Outline.** Near its end a tool is a cone (needle, pipette) or a flat tapered plate (jaw)
  ending in a rounded end: a sphere (needle), a circular corner (jaw) or the opening's ring
  (pipette). In the image that is a wedge of half-angle ``beta`` about the axis whose edges
  touch an ellipse centred on the *tip point* ``c``: ``rho`` across the axis, ``k rho`` along
  it (``k = 1`` for a sphere; a ring of normal ``a`` seen along ``w`` has ``k = |a.w|``, and
  the cone's half-angle ``alpha`` and the image's ``beta`` give it,
  ``k^2 = 1 - sin^2 alpha / sin^2 beta``; a plate has ``k = tan alpha / tan beta``). The
  wedge's vertex is ``D = rho sqrt(k^2 + cot^2 beta)`` ahead of ``c``; it is cut by the chord
  through the points of contact, ``k^2 rho^2 / D`` ahead of ``c``. A pipette's ring seen nearly
  edge-on is thinner than a subsample: its share of each is that of a band as thick as the
  ellipse's chord along the axis.
- **Light.** An opaque tool takes away a fixed share of the light. Glass refracts: a ray
  through a hollow cylinder (outer radius 1, inner ``1 - wall``) at ``xi`` from its axis
  crosses a path length ``2 (sqrt(1 - xi^2) - sqrt(ri^2 - xi^2))``, whose slope bends the ray,
  and what is bent beyond the objective's aperture is lost: the darkness is
  ``d0 + d1 (1 - exp(-|slope| / s0))``, dark walls around a lighter lumen. ``xi`` is the
  distance from the axis over the wedge's half-width behind the end, the ellipse's
  normalised radius within it; the loss is averaged over each subsample's width (from its
  running integral), so that the image is smooth in the parameters although the loss jumps
  at the lumen's wall.
- **Blur.** The outline's darkness is drawn on a grid of ``S x S`` subsamples per pixel
  (each box-filtered over its width), blurred by a Gaussian whose sigma is
  ``hypot(floor, a + g t)`` at ``t`` px behind the vertex (diffraction, and a defocus that
  changes along a tool held at an angle to the focal plane; interpolated between a few
  levels), and averaged over each pixel.
- **Image.** A quadratic background (level, gradient, curvature) minus the blurred darkness
  times the tool's contrast (for glass, two layers: its uniform and its refractive
  darkness), the darkness scaled by the background's light where the coarse search measured
  it (uneven illumination): the linear coefficients are solved for every trial outline
  (variable projection); the eight outline and blur parameters (:class:`ToolImageModel`) are
  fitted by Levenberg-Marquardt with a Jacobian of forward differences, from the best of a
  scan along the coarse axis; the window is drawn again around the fitted tip (at most
  three times) until the tip stays, so that a faint end the coarse search missed is
  followed.

The tip point's covariance is ``(J^T J)^-1 s^2`` from the Jacobian ``J`` at the solution
(central differences) and the residual variance ``s^2``, times how much neighbouring
residuals agree (``(1 + r) / (1 - r)`` along rows and columns, ``r`` their correlation: the
model's own mismatch is smooth, so it counts fewer times than white noise would).

Where it holds: this is the image of a tool under bright field as
:mod:`microcal.sim.tools` renders it (its glass loss with ``wall = 0.3`` and ``s0 = 1.2``):
on the simulator the model is the truth; on a real microscope, its figures hold only as far as
a real tool's image follows this model (the glass's profile, a Gaussian blur).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from .tip_find import ToolBlob
from .tip_fit import TipFit, _end_ratio, _noise, lowest_cost_fit, neighbour_correlation_factor
from .tip_target import TipTarget

__all__ = ["GLASS_SLOPE", "GLASS_WALL", "ToolImageModel", "fit_tip_image"]

#: The glass wall's thickness as a fraction of the outer radius.
GLASS_WALL = 0.3
#: The path length's slope at which the objective loses 1 - 1/e of the refracted light.
GLASS_SLOPE = 1.2
#: Subsamples per pixel along each side.
_SUB = 4
#: The Jacobian's difference steps: (px, rad, log, rad, px, log, px, px/px).
_STEPS = (0.02, 0.002, 0.005, 0.001, 0.02, 0.01, 0.01, 0.001)
#: Whether the background is a quadratic (else a plane) over the window.
_QUADRATIC = True
#: The fit's tolerances (relative change of the cost, of the scaled parameters).
_FTOL, _XTOL = 1e-5, 1e-5
#: Windows fitted at most: each is centred on the last fit's tip, until the tip stays.
_ATTEMPTS = 3
#: Ratio of neighbouring blur levels (the blur between them interpolated).
_LEVEL_RATIO = 1.15


def glass_loss(xi: FloatArray) -> FloatArray:
    """The refractive part of a glass tube's darkness at ``xi`` (0 on its axis, 1 at its edge)."""
    ri = 1.0 - GLASS_WALL
    x = np.clip(np.abs(xi), 0.0, 0.995)
    slope = x / np.sqrt(1.0 - x * x)
    slope = np.where(x < ri * 0.995, slope - x / np.sqrt(np.maximum(ri * ri - x * x, 1e-6)), slope)
    out: FloatArray = 1.0 - np.exp(-np.abs(slope) / GLASS_SLOPE)
    return out


_XI = np.linspace(0.0, 1.5, 3001)
_LOSS_SUM = np.concatenate(
    [[0.0], np.cumsum(0.5 * np.diff(_XI) * (glass_loss(_XI[1:]) + glass_loss(_XI[:-1])))]
)


def glass_loss_mean(xi: FloatArray, width: FloatArray | float) -> FloatArray:
    """:func:`glass_loss` averaged over ``[xi - width / 2, xi + width / 2]`` (``xi >= 0``; the
    loss is even in ``xi``), from its running integral: smooth in ``xi`` although the loss
    jumps at the lumen's wall."""
    half = np.maximum(0.5 * width, 1e-6)
    hi = np.interp(xi + half, _XI, _LOSS_SUM)
    lo = xi - half
    lo_sum = np.sign(lo) * np.interp(np.abs(lo), _XI, _LOSS_SUM)
    out: FloatArray = (hi - lo_sum) / (2.0 * half)
    return out


@dataclass(frozen=True)
class _Geometry:
    beta: float
    rho: float
    k: float
    D: float  # vertex ahead of the tip point, px
    tc: float  # the chord, along the axis from the tip point (negative: ahead), px


class ToolImageModel:
    """The tool's image over a window of ``gray`` for a parameter vector.

    The parameters are chosen so that the outline's edges and its end are nearly independent:
    ``(d, angle, log hm, beta, s, log floor, a, g)``: the axis passes through
    ``m = ref + d n_ref`` at ``angle``; ``hm`` is the outline's half-width at ``m``, ``beta``
    the edges' half-angle; the tip point is ``s`` px ahead of ``m`` on the axis (so the
    vertex is ``hm / tan(beta)`` ahead of ``m``, and the end's radius follows); the blur's
    sigma ``t`` px behind the vertex is ``hypot(0.25 + exp(log floor), a + g t)``.

    Parameters
    ----------
    gray : (H, W) float32
    target : TipTarget
    box : (x0, y0, x1, y1)
        The window's pixel box (end exclusive).
    mask : (h, w) bool
        The pixels of the box that the fit uses.
    ref : (2,) float
        A point near the middle of the window, whole-image pixels.
    normal : (2,) float
        Unit direction across the first axis.
    light : (H, W) float, optional
        The background's light over the whole image (uneven illumination), which scales the
        tool's darkness; uniform when not given.
    """

    def __init__(self, gray: NDArray[np.float32], target: TipTarget,
                 box: tuple[int, int, int, int], mask: NDArray[np.bool_], ref: FloatArray,
                 normal: FloatArray, light: NDArray[np.float32] | None = None) -> None:  # fmt: skip
        x0, y0, x1, y1 = box
        self.box, self.target, self.mask = box, target, mask
        self._sharp: tuple[tuple[bytes, int], list[NDArray[np.float32]]] | None = None
        self._last: tuple[FloatArray, FloatArray] | None = None
        self.ref = np.asarray(ref, dtype=np.float64) - (x0, y0)
        self.normal = np.asarray(normal, dtype=np.float64)
        self.shape = (y1 - y0, x1 - x0)
        self.values = gray[y0:y1, x0:x1].astype(np.float64)[mask]
        self.glass = target.kind in ("pipette", "any")
        self.ring = target.kind == "pipette"
        h, w = self.shape
        yy, xx = np.nonzero(mask)
        self.rows, self.cols = yy, xx
        # The tool takes away a share of the light that falls there: its darkness is scaled by
        # the background's light (uneven illumination), when it is known.
        self.light = np.ones(yy.size)
        if light is not None:
            lit = np.asarray(light, dtype=np.float64)[y0:y1, x0:x1][mask]
            self.light = lit / max(float(np.mean(lit)), 1e-12)
        cx, cy = (w - 1) / 2, (h - 1) / 2
        gx, gy = (xx - cx) / max(w, 1), (yy - cy) / max(h, 1)
        cols = [np.ones(yy.size), gx, gy]
        if _QUADRATIC:
            cols += [gx * gx, gx * gy, gy * gy]
        self.plane = np.column_stack(cols)

    def outline(self, p: FloatArray) -> tuple[FloatArray, FloatArray, _Geometry]:
        """(tip point in the box's pixels, unit axis, geometry) of a parameter vector."""
        u = np.array([math.cos(p[1]), math.sin(p[1])])
        m = self.ref + self.normal * p[0]
        beta = float(np.clip(p[3], 0.005, 1.2))
        hm = math.exp(float(np.clip(p[2], -6.0, 5.0)))
        k = _end_ratio(self.target, beta)
        cot = math.cos(beta) / math.sin(beta)
        root = math.sqrt(k * k + cot * cot)
        D = max(hm * cot - p[4], 1e-3 * root)
        rho = D / root
        tip = m - u * p[4]
        return tip, u, _Geometry(beta, rho, k, D, -k * k * rho * rho / D)

    def parameters(self, tip: FloatArray, u: FloatArray, beta: float, rho: float,
                   blur: FloatArray) -> FloatArray:  # fmt: skip
        """The parameter vector of an outline (tip point in the box's pixels, unit axis)."""
        # where the axis crosses the line through ref across the first axis
        A = np.column_stack([self.normal, u])
        d, back = np.linalg.solve(A, tip - self.ref)
        s = -back
        k = _end_ratio(self.target, beta)
        cot = math.cos(beta) / math.sin(beta)
        D = rho * math.sqrt(k * k + cot * cot)
        hm = (s + D) * math.tan(beta)
        return np.array([d, math.atan2(u[1], u[0]), math.log(max(hm, 1e-3)), beta, s, *blur])

    def sigma(self, p: FloatArray, t_vertex: FloatArray) -> FloatArray:
        """The blur's sigma at ``t_vertex`` px behind the vertex, px."""
        floor = 0.25 + math.exp(float(np.clip(p[5], -8.0, 3.0)))
        out: FloatArray = np.hypot(floor, p[6] + p[7] * np.maximum(t_vertex, 0.0))
        return out

    def layers(self, p: FloatArray) -> list[FloatArray]:
        """The blurred darkness layers over the box's pixels, each (h, w)."""
        tip, u, g = self.outline(p)
        h, w = self.shape
        c, s = float(u[0]), float(u[1])
        # the blur's largest sigma over the box, for the padding
        corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
        tv = (corners[:, 0] - tip[0]) * c + (corners[:, 1] - tip[1]) * s + g.D
        sig_hi = float(np.max(self.sigma(p, tv)))
        pad = min(math.ceil(3.0 * sig_hi) + 2, 40)
        n = _SUB
        key = (p[:5].tobytes(), pad)
        if self._sharp is not None and self._sharp[0] == key:
            pixels = self._sharp[1]  # only the blur changed
        else:
            pixels = self._sharp_layers(tip, c, s, g, pad, n)
            self._sharp = (key, pixels)
        # the blur's sigma at each pixel, from its distance behind the vertex
        px = np.arange(-pad, w + pad) - tip[0]
        py = np.arange(-pad, h + pad)[:, None] - tip[1]
        sig = self.sigma(p, px * c + py * s + g.D)
        out = []
        for layer in pixels:
            blurred = _blur_levels(layer, sig)
            out.append(blurred[pad : pad + h, pad : pad + w].astype(np.float64))
        return out

    def _sharp_layers(self, tip: FloatArray, c: float, s: float, g: _Geometry, pad: int,
                      n: int) -> list[NDArray[np.float32]]:  # fmt: skip
        """The outline's darkness layers averaged over each pixel of the padded box (not
        blurred): only the pixels within reach of the outline are taken in subsamples."""
        h, w = self.shape
        hp, wp = h + 2 * pad, w + 2 * pad
        px = np.arange(-pad, w + pad) - tip[0]
        py = np.arange(-pad, h + pad)[:, None] - tip[1]
        t = px * c + py * s
        x = py * c - px * s
        # a pixel's subsamples are within 0.71 px of its centre: beyond 1 px from the
        # outline (the taper's distance, a circle around the end) none is covered
        taper = np.maximum(np.abs(x) * math.cos(g.beta) - (t + g.D) * math.sin(g.beta), g.tc - t)
        near = (taper < 1.0) | (np.hypot(t, x) < g.rho + 1.0)
        iy, ix = np.nonzero(near)
        off = (np.arange(n) + 0.5) / n - 0.5
        ox, oy = (a.ravel() for a in np.meshgrid(off, off))
        ts = t[iy, ix][:, None] + (ox * c + oy * s)[None, :]
        xs = np.abs(x[iy, ix][:, None] + (oy * c - ox * s)[None, :])
        dark = _darkness(ts, xs, g, 1.0 / n, self.ring, self.glass)
        out = []
        for layer in dark:
            full = np.zeros((hp, wp), dtype=np.float32)
            full[iy, ix] = layer.mean(axis=1)
            out.append(full)
        return out

    def design(self, p: FloatArray) -> FloatArray:
        """The design matrix over the fitted pixels: the plane and the darkness layers."""
        cols = [self.plane] + [
            -(lay[self.rows, self.cols] * self.light)[:, None] for lay in self.layers(p)
        ]
        return np.hstack(cols)

    def solve(self, p: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(residuals, linear coefficients) of a parameter vector."""
        A = self.design(p)
        G = A.T @ A
        coef = np.linalg.solve(G + 1e-10 * np.trace(G) * np.eye(len(G)), A.T @ self.values)
        out: FloatArray = self.values - A @ coef
        return out, coef

    def residuals(self, p: FloatArray) -> FloatArray:
        """The residuals over the fitted pixels (the linear coefficients solved for)."""
        out = self.solve(p)[0]
        self._last = (p.copy(), out)
        return out

    def jacobian(self, p: FloatArray, central: bool = False) -> FloatArray:
        """The residuals' Jacobian by forward (or central) differences of fixed steps, (N, 8).

        The image is drawn on subsamples, so it is smooth in the parameters only at the
        scale of a subsample's share: the steps are a few hundredths of a pixel.
        """
        last = self._last
        r0 = last[1] if last is not None and np.array_equal(last[0], p) else self.residuals(p)
        J = np.empty((r0.size, p.size))
        for i in (5, 6, 7, 0, 1, 2, 3, 4):  # the blur first: the sharp outline is kept
            h = _STEPS[i]
            q = p.copy()
            q[i] += h
            if central:
                q2 = p.copy()
                q2[i] -= h
                J[:, i] = (self.solve(q)[0] - self.solve(q2)[0]) / (2 * h)
            else:
                J[:, i] = (self.solve(q)[0] - r0) / h
        return J


def _darkness(
    t: FloatArray, x: FloatArray, g: _Geometry, width: float, ring: bool, glass: bool
) -> list[FloatArray]:
    """The outline's darkness layers at subsample centres (t along from the tip point, x =
    |across|), each box-filtered over ``width``: the coverage, and for glass the coverage
    times its refractive loss."""
    sb, cb = math.sin(g.beta), math.cos(g.beta)
    half = 0.5 * width
    taper = np.maximum(x * cb - (t + g.D) * sb, g.tc - t)
    kr = max(g.k * g.rho, 0.02)
    u, v = t / kr, x / g.rho
    re = np.sqrt(u * u + v * v)
    end = (re - 1.0) * min(kr, g.rho)
    if ring:
        chord = kr * np.sqrt(np.clip(1.0 - v * v, 0.0, 1.0))
        end_cover = np.clip((np.minimum(chord, t + half) - np.maximum(-chord, t - half)) / width,
                            0.0, 1.0)  # fmt: skip
    else:
        end_cover = np.clip(0.5 - end / width, 0.0, 1.0)
    cover = np.maximum(np.clip(0.5 - taper / width, 0.0, 1.0), end_cover)
    if not glass:
        return [cover]
    # Behind the end, xi is the distance from the axis over the wedge's half-width; within the
    # end, the ellipse's normalised radius. Each is averaged over the subsample's width, and
    # the two blend over a subsample at their boundary (so that the image is smooth in the
    # parameters).
    # Only where the outline covers the subsample.
    on = np.nonzero(cover > 0.0)
    ton, xon, reon = t[on], x[on], re[on]
    hw = np.maximum((ton + g.D) * math.tan(g.beta), 1e-3)
    wedge = glass_loss_mean(np.minimum(xon / hw, 1.5), width / hw)
    ring_ = glass_loss_mean(np.minimum(reon, 1.5), width / min(kr, g.rho) * 0.5 + width / g.rho)
    share = np.clip(0.5 - (taper[on] - end[on]) / width, 0.0, 1.0)
    loss = np.zeros_like(cover)
    loss[on] = cover[on] * (share * wedge + (1.0 - share) * ring_)
    return [cover, loss]


def _correlation_factor(model: ToolImageModel, resid: FloatArray) -> float:
    """:func:`~microcal.vision.tip_fit.neighbour_correlation_factor` of the model's pixels."""
    field = np.full(model.shape, np.nan)
    field[model.rows, model.cols] = resid
    return neighbour_correlation_factor(field)


def _blur_levels(image: NDArray[np.float32], sigma: FloatArray) -> NDArray[np.float32]:
    """Gaussian blur whose sigma varies per sample, interpolated between levels."""
    lo, hi = float(sigma.min()), float(sigma.max())
    if hi - lo < 0.02 * lo + 1e-3:
        flat: NDArray[np.float32] = cv2.GaussianBlur(image, (0, 0), max(0.5 * (lo + hi), 1e-3))
        return flat
    step = math.log(_LEVEL_RATIO)
    n = max(2, math.ceil(math.log(hi / lo) / step) + 1)
    levels = lo * np.exp(step * np.arange(n))
    k = np.clip(np.log(sigma / lo) / step, 0, n - 1 - 1e-9)
    i = np.floor(k).astype(int)
    f = (k - i).astype(np.float32)
    out = np.zeros_like(image)
    for j in range(n):
        wj = np.where(i == j, 1 - f, 0) + np.where(i == j - 1, f, 0)
        if np.any(wj):
            out += wj.astype(np.float32) * cv2.GaussianBlur(image, (0, 0), float(levels[j]))
    return out


def _window(
    gray_shape: tuple[int, int], tip: FloatArray, u: FloatArray, beta: float, blur: float,
    front_px: float, back_px: float,
) -> tuple[tuple[int, int, int, int], NDArray[np.bool_]] | None:  # fmt: skip
    """The box and the pixels of it within reach of the outline: from ``front_px`` ahead of
    the tip to ``back_px`` behind it, a margin of 3 blurs and 2 px beside the edges."""
    H, W = gray_shape
    n = np.array([-u[1], u[0]])
    margin = 3.0 * blur + 2.5
    hw_back = back_px * math.tan(beta) + margin + 1.0
    pts = np.array([tip - u * front_px + n * s * (margin + 1.0) for s in (-1, 1)]
                   + [tip + u * back_px + n * s * hw_back for s in (-1, 1)])  # fmt: skip
    x0, y0 = np.floor(pts.min(axis=0)).astype(int)
    x1, y1 = np.ceil(pts.max(axis=0)).astype(int) + 1
    x0, y0, x1, y1 = max(x0, 0), max(y0, 0), min(x1, W), min(y1, H)
    if x1 - x0 < 8 or y1 - y0 < 8:
        return None
    yy, xx = np.mgrid[y0:y1, x0:x1].astype(np.float64)
    t = (xx - tip[0]) * u[0] + (yy - tip[1]) * u[1]
    x = np.abs((xx - tip[0]) * n[0] + (yy - tip[1]) * n[1])
    mask = (t >= -front_px) & (t <= back_px)
    mask &= x <= np.maximum(t, 0.0) * math.tan(beta) + margin + 1.0
    return (int(x0), int(y0), int(x1), int(y1)), mask


def fit_tip_image(
    gray: NDArray[np.float32],
    start: ToolBlob | TipFit,
    target: TipTarget,
    *,
    back_px: float = 24.0,
) -> TipFit | str:
    """Fit the tool's image around a first tip (a coarse blob or another fit's answer).

    Parameters
    ----------
    gray : (H, W) float32
    start : ToolBlob or TipFit
        Where to start: the tip, the axis, the half-angle (and the blur, from a fit).
    target : TipTarget
    back_px : float
        How far behind the tip the window reaches along the axis, px.

    Returns
    -------
    TipFit or str
        The fitted tip (whole-image pixels) or why the fit failed.
    """
    light = None if isinstance(start, TipFit) else start.background
    if isinstance(start, TipFit):
        tip, axis = start.apex_px.copy(), start.axis.copy()
        beta0, blur0, rho0 = start.half_angle_rad, start.blur_px, max(start.end_radius_px, 0.2)
        shifts = [0.0]
    else:
        tip, axis = start.tip_px.copy(), start.axis.copy()
        beta0, blur0, rho0 = float(np.clip(start.half_angle_rad, 0.02, 0.6)), 1.0, 0.8
        shifts = list(np.arange(-4.0, 4.5, 1.0))
    fit = None
    model = None
    scale = np.array([0.1, 0.01, 0.05, 0.01, 0.2, 0.2, 0.2, 0.01])
    blur = np.array([math.log(max(blur0 - 0.25, 0.05)), 0.0, 0.02])
    for _attempt in range(_ATTEMPTS):
        win = _window(gray.shape, tip, axis, beta0, blur0, 4.0 + 3.0 * blur0,
                      back_px + 2.0 * blur0)  # fmt: skip
        if win is None:
            return "the tip is at the edge of the field"
        box, mask = win
        ref = tip + axis * (0.5 * back_px)
        model = ToolImageModel(gray, target, box, mask, ref, np.array([-axis[1], axis[0]]),
                               light)  # fmt: skip
        p0 = model.parameters(tip - box[:2], axis, beta0, rho0, blur)
        starts = [p0]
        if len(shifts) > 1:  # the tip's place along the axis: the best of a scan
            scan = []
            for sft in shifts:
                q = model.parameters(tip - box[:2] + axis * sft, axis, beta0, rho0, blur)
                scan.append((float(np.sum(model.residuals(q) ** 2)), sft, q))
            scan.sort(key=lambda v: v[0])
            starts = [scan[0][2]]
        fit = lowest_cost_fit(
            model.residuals,
            starts,
            jac=model.jacobian,
            method="lm",
            x_scale=scale,
            max_nfev=100,
            ftol=_FTOL,
            xtol=_XTOL,
        )
        if fit is None:
            return "the model fit failed on this image"
        p = fit.x
        new_tip, new_axis, g = model.outline(p)
        new_tip = new_tip + box[:2]
        new_blur = float(model.sigma(p, np.array([g.D]))[0])
        settled = (np.hypot(*(new_tip - tip)) < 1.0 and abs(new_blur - blur0) < 0.5 * blur0
                   and abs(g.beta - beta0) < 0.3 * beta0)  # fmt: skip
        tip, axis, beta0, blur0, rho0 = new_tip, new_axis, g.beta, new_blur, g.rho
        blur = np.array([math.log(max(blur0 - 0.25, 0.05)), 0.0, 0.02])
        shifts = [0.0]
        if settled:
            break
    assert fit is not None
    assert model is not None
    p = fit.x
    resid, coef = model.solve(p)
    n_px, m = resid.size, p.size + coef.size
    rss = float(resid @ resid)
    J = model.jacobian(p, central=True)
    cov_p = np.linalg.pinv(J.T @ J) * rss / max(n_px - m, 1)
    T = np.zeros((2, p.size))  # d(tip point) / d(parameters)
    for i in range(p.size):
        step = np.zeros(p.size)
        step[i] = 1e-6
        T[:, i] = (model.outline(p + step)[0] - model.outline(p - step)[0]) / 2e-6
    cov = T @ cov_p @ T.T * _correlation_factor(model, resid)
    if not np.all(np.isfinite(cov)) or min(np.linalg.eigvalsh(cov)) <= 0:
        return "the model fit is degenerate (the tool's outline is not seen)"
    _, u, g = model.outline(p)
    level = float(coef[0])
    nb = model.plane.shape[1]
    darkest = float(coef[nb]) + (max(float(coef[nb + 1]), 0.0) if model.glass else 0.0)
    x0, y0, x1, y1 = model.box
    return TipFit(
        apex_px=tip, cov_px=cov, axis=u, vertex_px=tip - u * g.D,
        half_angle_rad=g.beta, end_radius_px=g.rho, blur_px=blur0,
        contrast=darkest / max(abs(level), 1e-9), rms=math.sqrt(rss / n_px),
        noise=_noise(gray[y0:y1, x0:x1]),
    )  # fmt: skip
