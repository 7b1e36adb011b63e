"""The tip from the tool's profiles: scan lines across the taper, the darkness along its axis.

A fast estimator of the tip point (a few milliseconds on a 256 x 256 region) that does not
depend on how the light falls off across the tool (an opaque cone, or glass whose walls are
dark and whose lumen is lighter): only on the outline's geometry.

- The image is sampled on lines across the coarse axis (bilinear, 1 px apart along it,
  0.5 px across), and divided by the background's light, fitted on both flanks of the tool
  (a cubic along the axis, a slope across it that may change along it): the darkness
  ``d = 1 - I / B``.
- The two outer edges (the strongest rise and fall of the darkness on each scan line, to
  sub-pixel by a parabola) give two lines: their bisector near the tip is the axis, and far
  behind it, on the lines whose edges are nearly as sharp as the sharpest (the blur grows
  along a tool held at an angle) and wide against the blur, their angle is the taper's
  angle in the image. Where the edges are too soft, the axis is the line through each scan
  line's centroid of darkness (on the axis for any symmetric profile), weighted by the
  darkness. The window is sampled again along the axis found.
- The darkness summed across each scan line, ``M(t)``, is the tool's half-width ``h(t)``
  times twice its mean darkness, blurred along the axis, whatever the profile across: a
  ramp from the taper's vertex behind the end, the end's ellipse (``rho`` across, ``k rho``
  along, ``k`` from the kind and the taper as in :mod:`~microcal.vision.tip_fit`) in front
  of where the edges touch it. ``h`` is piecewise linear through points on the ellipse and
  the ramp; blurred by a Gaussian it is a sum of ``sigma psi((t - t_i) / sigma)`` with
  ``psi(z) = z Phi(z) + phi(z)``, in closed form. Its three parameters (the tip point along
  the axis, its distance from the vertex, the blur) are fitted by Levenberg-Marquardt, the
  level and the darkness by least squares for each. The strip summed across ends 1.5 blurs
  beyond the outline and widens along the tool (its blur grows when it is held at an angle);
  the darkness of the background just beside it (both sides, five scan lines) is taken out.

The tip point is on the fitted axis at the fitted place along it; its covariance is the
fits': along the axis from the profile's fit, across it from the axis's line.
"""

from __future__ import annotations

import math

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from .._validation import FloatArray
from .tip_find import ToolBlob
from .tip_fit import TipFit, _end_ratio, _noise
from .tip_target import TipTarget

__all__ = ["profile_tip"]

#: Spacing of the samples across the axis, px.
_DX = 0.5
#: Points on the end's ellipse (the piecewise-linear half-width).
_KNOTS = 10
_SQRT_2PI = math.sqrt(2.0 * math.pi)


def _psi(z: FloatArray) -> FloatArray:
    """``z Phi(z) + phi(z)``: a unit ramp blurred by a unit Gaussian."""
    out: FloatArray = z * ndtr(z) + np.exp(-0.5 * z * z) / _SQRT_2PI
    return out


class _Frame:
    """Scan lines across an axis: the image sampled at ``origin + t u + x n``."""

    def __init__(self, gray: NDArray[np.float32], origin: FloatArray, u: FloatArray,
                 front: float, back: float, half: float) -> None:  # fmt: skip
        self.origin, self.u = origin, u
        self.n = np.array([-u[1], u[0]])
        self.t = np.arange(-front, back + 0.5, 1.0)
        self.x = np.arange(-half, half + 1e-9, _DX)
        T, X = np.meshgrid(self.t, self.x, indexing="ij")
        mx = (origin[0] + T * u[0] + X * self.n[0]).astype(np.float32)
        my = (origin[1] + T * u[1] + X * self.n[1]).astype(np.float32)
        self.values = cv2.remap(gray, mx, my, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT,
                                borderValue=float("nan")).astype(np.float64)  # fmt: skip
        self.T, self.X = T, X

    def darkness(self, centre: FloatArray, inner: FloatArray, outer: FloatArray) -> FloatArray:
        """``1 - I / B``: B fitted on the flanks ``inner < |x - centre| < outer`` per line."""
        off = np.abs(self.X - centre[:, None])
        flank = (off > inner[:, None]) & (off < outer[:, None]) & np.isfinite(self.values)
        t = self.T / max(float(np.ptp(self.t)), 1.0)
        x = self.X / max(float(np.ptp(self.x)), 1.0)
        cols = [np.ones_like(t), t, t * t, t**3, x, x * t, x * t * t]
        A = np.stack([c[flank] for c in cols], axis=1)
        b = self.values[flank]
        if b.size < 3 * len(cols):
            return np.full_like(self.values, np.nan)
        keep = np.ones(b.size, dtype=bool)
        for _ in range(2):  # leave out what is darker than the texture (debris, a second tool)
            coef = _least_squares(A[keep], b[keep])
            resid = b - A @ coef
            spread = 1.4826 * float(np.median(np.abs(resid[keep]))) + 1e-9
            keep = np.abs(resid) < 3.0 * spread
        light = sum(c * k for c, k in zip(cols, coef, strict=True))
        out: FloatArray = 1.0 - self.values / np.maximum(light, 1e-6)
        return out


def _local(d: FloatArray, X: FloatArray, centre: FloatArray, strip: FloatArray,
           width: float, rows: int) -> FloatArray:  # fmt: skip
    """``d`` less the darkness of the background beside the strip on each scan line: the
    mean over bands ``width`` wide on both sides of it, over ``rows`` neighbouring lines."""
    off = X - centre[:, None]
    sides = []
    for sign in (-1.0, 1.0):
        band = (sign * off > strip[:, None] + 0.5) & (sign * off < strip[:, None] + 0.5 + width)
        band &= np.isfinite(d)
        total = np.where(band, d, 0.0).sum(axis=1)
        count = band.sum(axis=1).astype(float)
        kernel = np.ones(rows)
        total = np.convolve(total, kernel, mode="same")
        count = np.convolve(count, kernel, mode="same")
        sides.append(np.where(count > 0, total / np.maximum(count, 1.0), 0.0))
    out: FloatArray = d - (0.5 * (sides[0] + sides[1]))[:, None]
    return out


def _least_squares(A: FloatArray, b: FloatArray) -> FloatArray:
    """Least squares by the normal equations (small systems; no threaded BLAS call)."""
    G = np.einsum("ij,ik->jk", A, A)
    out: FloatArray = np.linalg.solve(G + 1e-12 * np.trace(G) * np.eye(len(G)),
                                      np.einsum("ij,i->j", A, b))  # fmt: skip
    return out


def _rows(d: FloatArray, x: FloatArray, centre: FloatArray, half: FloatArray
          ) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """Per scan line: the darkness summed across the strip ``|x - centre| < half`` and its
    centroid."""
    inside = np.abs(x[None, :] - centre[:, None]) < half[:, None]
    dd = np.where(inside & np.isfinite(d), d, 0.0)
    m0 = dd.sum(axis=1) * _DX
    m1 = (dd * x[None, :]).sum(axis=1) * _DX
    return m0, m1 / np.where(np.abs(m0) > 1e-9, m0, np.nan)


def _edges(d: FloatArray, x: FloatArray, centre: FloatArray, half: FloatArray
           ) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """Per scan line: the outer edges (strongest rise left of the centre, strongest fall
    right of it, to sub-pixel) and the weaker of the two slopes."""
    g = np.full_like(d, np.nan)
    g[:, 1:-1] = (d[:, 2:] - d[:, :-2]) / (2 * _DX)
    off = x[None, :] - centre[:, None]
    inside = np.abs(off) < half[:, None]
    left = np.where(inside & (off < 0), g, -np.inf)
    right = np.where(inside & (off > 0), -g, -np.inf)
    left = np.where(np.isfinite(left), left, -np.inf)
    right = np.where(np.isfinite(right), right, -np.inf)
    out = []
    strength = []
    rows = np.arange(d.shape[0])
    for side in (left, right):
        i = np.clip(np.argmax(side, axis=1), 1, d.shape[1] - 2)
        y0, y1, y2 = side[rows, i - 1], side[rows, i], side[rows, i + 1]
        with np.errstate(invalid="ignore", divide="ignore"):
            den = y0 - 2 * y1 + y2
            shift = np.where(np.isfinite(den) & (den < 0), 0.5 * (y0 - y2) / den, 0.0)
        out.append(x[i] + np.clip(shift, -1.0, 1.0) * _DX)
        strength.append(y1)
    return out[0], out[1], np.minimum(strength[0], strength[1])


def _line(t: FloatArray, y: FloatArray, w: FloatArray) -> tuple[FloatArray, float] | None:
    """A robust weighted line ``y = a + b t``: (a, b) and the variance at t = 0 per unit of
    the residuals, or None."""
    ok = np.isfinite(y) & np.isfinite(w) & (w > 0)
    for _ in range(3):
        if ok.sum() < 4:
            return None
        A = np.column_stack([np.ones(ok.sum()), t[ok]]) * np.sqrt(w[ok])[:, None]
        coef = _least_squares(A, y[ok] * np.sqrt(w[ok]))
        resid = y - (coef[0] + coef[1] * t)
        spread = 1.4826 * float(np.median(np.abs(resid[ok]))) + 1e-6
        new = ok & (np.abs(resid) < 3.0 * spread)
        new |= np.isfinite(y) & np.isfinite(w) & (w > 0) & (np.abs(resid) < 3.0 * spread)
        if np.array_equal(new, ok):
            break
        ok = new
    A = np.column_stack([np.ones(ok.sum()), t[ok]]) * np.sqrt(w[ok])[:, None]
    r = (y[ok] - (coef[0] + coef[1] * t[ok])) * np.sqrt(w[ok])
    s2 = float(r @ r) / max(int(ok.sum()) - 2, 1)
    cov = np.linalg.pinv(A.T @ A) * s2
    return np.asarray(coef, dtype=np.float64), float(cov[0, 0])


class _Along:
    """The darkness summed across, ``c0 + s (G_sigma * h)(t)``, for ``(tc, log D, log sigma)``:
    ``h`` the outline's half-width with its tip point at ``tc`` and its vertex ``D`` before."""

    def __init__(self, t: FloatArray, m0: FloatArray, beta: float, target: TipTarget) -> None:
        self.t, self.m0 = t, m0
        self.beta = beta
        self.k = _end_ratio(target, beta)
        sb, cb = math.sin(beta), math.cos(beta)
        k = self.k
        self.rho_per_d = 1.0 / math.sqrt(k * k + (cb / sb) ** 2)
        # Where the edges touch the ellipse, behind its centre (units of rho), and its angle.
        contact = -k * k * sb / math.sqrt(k * k * sb * sb + cb * cb)
        cos_con = float(np.clip(-contact / k, -1.0, 1.0))
        theta = np.linspace(0.0, math.acos(cos_con), _KNOTS + 1)
        self.knot_t = -k * np.cos(theta)  # units of rho, from the tip point
        self.knot_h = np.sin(theta)
        self.tan_beta = math.tan(beta)

    def curve(self, p: FloatArray) -> FloatArray:
        """``G_sigma * h`` at the scan lines."""
        tc, D, sigma = p[0], math.exp(p[1]), math.exp(p[2])
        rho = D * self.rho_per_d
        kt = tc + rho * self.knot_t
        kh = rho * self.knot_h
        slopes = np.empty(kt.size)  # the slope after each knot; the ramp after the last
        seg = np.diff(kt)
        slopes[:-1] = np.diff(kh) / np.where(seg > 1e-12, seg, 1e-12)
        slopes[-1] = self.tan_beta
        change = np.diff(np.concatenate([[0.0], slopes]))
        z = (self.t[:, None] - kt[None, :]) / sigma
        out: FloatArray = sigma * (_psi(z) @ change)
        return out

    def solve(self, p: FloatArray) -> tuple[FloatArray, FloatArray]:
        """(residuals, (c0, s)) of a parameter vector."""
        c = self.curve(p)
        n, sc, scc = c.size, float(c.sum()), float(c @ c)
        sm, scm = float(self.m0.sum()), float(c @ self.m0)
        det = n * scc - sc * sc
        if abs(det) < 1e-12 * max(n * scc, 1e-30):
            coef = np.array([sm / n, 0.0])
        else:
            coef = np.array([(scc * sm - sc * scm) / det, (n * scm - sc * sm) / det])
        out: FloatArray = self.m0 - coef[0] - coef[1] * c
        return out, coef

    def fit(self, p: FloatArray) -> tuple[FloatArray, FloatArray, float]:
        """Levenberg-Marquardt from ``p``: (p, covariance of p and (c0, s), residual RMS)."""
        r, _ = self.solve(p)
        cost = float(r @ r)
        lam = 1e-3
        steps = np.array([1e-3, 1e-3, 1e-3])
        for _ in range(40):
            J = np.empty((r.size, 3))
            for j in range(3):
                q = p.copy()
                q[j] += steps[j]
                J[:, j] = (self.solve(q)[0] - r) / steps[j]
            H = J.T @ J
            g = J.T @ r
            done = False
            while True:
                try:
                    delta = -np.linalg.solve(H + lam * np.diag(np.diag(H) + 1e-12), g)
                except np.linalg.LinAlgError:
                    return p, np.full((5, 5), np.nan), math.nan
                delta[1:] = np.clip(delta[1:], -0.7, 0.7)
                delta[0] = float(np.clip(delta[0], -3.0, 3.0))
                q = p + delta
                q[2] = min(q[2], math.log(12.0))
                r_new, _ = self.solve(q)
                c_new = float(r_new @ r_new)
                if c_new < cost:
                    p, r, lam = q, r_new, max(lam / 4, 1e-7)
                    small = bool(np.all(np.abs(delta) < 1e-5))
                    done = abs(cost - c_new) < 1e-10 * max(cost, 1e-30) or small
                    cost = c_new
                    break
                lam *= 8
                if lam > 1e8:
                    done = True
                    break
            if done:
                break
        # The covariance of all five (tc, log D, log sigma, c0, s), from the full Jacobian.
        _, coef = self.solve(p)
        full = np.empty((r.size, 5))
        base = coef[0] + coef[1] * self.curve(p)
        for j in range(3):
            q = p.copy()
            q[j] += steps[j]
            full[:, j] = (coef[0] + coef[1] * self.curve(q) - base) / steps[j]
        full[:, 3] = 1.0
        full[:, 4] = self.curve(p)
        dof = max(r.size - 5, 1)
        cov = np.linalg.pinv(full.T @ full) * cost / dof
        return p, cov, math.sqrt(cost / r.size)


def _taper(gray: NDArray[np.float32], origin: FloatArray, u: FloatArray, beta: float,
           sigma: float, reach: float) -> tuple[float, float, float, float] | None:  # fmt: skip
    """The outer edges far behind the tip, where the tool is wide against the blur: (half-angle,
    the bisector's offset and slope in the frame, the offset's variance), or None."""
    start = 12.0 + 3.0 * sigma
    margin = 3.0 * sigma + 1.5
    half = (reach + start) * math.tan(beta) + 2.0 * margin + 10.0
    frame = _Frame(gray, origin + u * start, u, 0.0, reach, half)
    hw = (frame.t + start + reach * 0.1) * math.tan(beta) * 1.3 + 1.0
    centre = np.zeros_like(frame.t)
    d = frame.darkness(centre, hw + margin, hw + margin + 8.0)
    xl, xr, strength = _edges(d, frame.x, centre, hw + margin)
    # The blur grows along a tool held at an angle: keep the lines whose edges are nearly as
    # sharp as the sharpest (their slope is the darkness over the blur) and wide against it.
    good = np.isfinite(strength) & (strength > 0)
    if good.sum() < 8:
        return None
    top = float(np.percentile(strength[good], 90))
    blur = sigma * top / np.where(good, strength, np.inf)
    wide = good & (strength > 0.6 * top) & ((xr - xl) > np.maximum(_WIDE * blur, 3.0))
    if wide.sum() < 8:
        wide = good & (strength > 0.5 * top) & ((xr - xl) > np.maximum(3.0 * blur, 2.0))
    ones = np.ones(int(wide.sum()))
    left = _line(frame.t[wide] + start, xl[wide], ones)
    right = _line(frame.t[wide] + start, xr[wide], ones)
    if left is None or right is None:
        return None
    b = 0.5 * (math.atan(right[0][1]) - math.atan(left[0][1]))
    if not 0.005 < b < 0.8:
        return None
    a1 = math.tan(0.5 * (math.atan(right[0][1]) + math.atan(left[0][1])))
    return b, 0.5 * (left[0][0] + right[0][0]), a1, 0.25 * (left[1] + right[1])


#: How much wider the strip summed across grows per px behind the tip (the blur of a tool
#: held at an angle to the focal plane grows along it).
_GROWTH = 0.15
#: Where the strip summed across ends beyond the outline, in blurs (a blurred edge's darkness
#: beyond it is 3 % of a blur's width; the background's texture grows with the strip).
_TAIL = 1.5
#: Width of the bands beside the strip where the background's texture is measured, px, and
#: the scan lines it is averaged over.
_LOCAL_PX = 3.0
_LOCAL_LINES = 5
#: Least width of the tool, in blurs, where its edges give the taper's angle.
_WIDE = 6.0
#: How far behind the tip the edges are followed, px.
_REACH_PX = 90.0


def profile_tip(gray: NDArray[np.float32], blob: ToolBlob, target: TipTarget) -> TipFit | str:
    """The tip point by the profiles of the tool (see the module docstring)."""
    h, w = gray.shape
    origin = blob.tip_px.astype(np.float64)
    u = blob.axis.astype(np.float64)
    beta = float(np.clip(blob.half_angle_rad, 0.02, 0.6))
    sigma = 1.5
    D = rho = math.nan
    fit = None
    for attempt in range(3):
        n = np.array([-u[1], u[0]])
        # The axis and the taper's angle from the edges far behind the tip.
        taper = _taper(gray, origin, u, beta, sigma, _REACH_PX)
        if taper is not None:
            beta = taper[0]
        # The darkness summed across, near the tip, along the axis.
        front = 8.0 + 4.0 * sigma
        back = 40.0 + 2.0 * sigma
        margin = 3.0 * sigma + 1.5
        wide = 1.0 if fit is not None else 1.6  # the coarse angle may be too narrow
        half = (back + (D if math.isfinite(D) else 10.0)) * math.tan(beta) * wide + margin + 10.0
        frame = _Frame(gray, origin, u, front, back, half)
        t = frame.t
        if fit is None:  # the coarse outline, widely
            hw = np.maximum(t + 5.0, 0.0) * math.tan(beta) * wide + 1.0
            strip = hw + margin
        else:  # the fitted outline
            hw = np.maximum((t + D) * math.tan(beta), rho)
            strip = hw + _TAIL * sigma + 0.5 + _GROWTH * np.maximum(t, 0.0)
        centre = np.zeros_like(t)
        inner = hw + margin
        d = frame.darkness(centre, inner, inner + 8.0)
        if not np.any(np.isfinite(d)):
            return "the tool's flanks are out of the field"
        if fit is not None:  # the background's texture beside the tool taken out
            d = _local(d, frame.X, centre, strip, _LOCAL_PX, _LOCAL_LINES)
        m0, x0 = _rows(d, frame.x, centre, strip)
        # The axis: the centroids behind the end, weighted by the darkness.
        behind = t > 2.0 * sigma + 1.0
        line = _line(t[behind], x0[behind], np.clip(m0[behind], 0.0, None) ** 2)
        if line is None:
            return "the tool's axis is not seen (too few scan lines across it)"
        (a0, a1), var_across = line
        centre = a0 + a1 * t
        # ... or better, where the edges are sharp: the bisector of the outer edges near the
        # tip (the centroids take in the background's texture beside the tool).
        xl, xr, strength = _edges(d, frame.x, centre, inner)
        sharp = behind & ((xr - xl) > max(3.0 * sigma, 2.0)) & (strength > 0)
        if sharp.sum() >= 8:
            ones = np.ones(int(sharp.sum()))
            left, right = _line(t[sharp], xl[sharp], ones), _line(t[sharp], xr[sharp], ones)
            if left is not None and right is not None:
                a0 = 0.5 * (left[0][0] + right[0][0])
                a1 = math.tan(0.5 * (math.atan(right[0][1]) + math.atan(left[0][1])))
                var_across = 0.25 * (left[1] + right[1])
                centre = a0 + a1 * t
        m0, _ = _rows(d, frame.x, centre, strip)
        ok = np.isfinite(m0)
        along = _Along(t[ok], m0[ok], beta, target)
        starts = []
        for shift in (-2.0, 0.0, 2.0):
            D0 = D if math.isfinite(D) else max(2.0, 1.0 / math.tan(beta))
            p0 = np.array([shift, math.log(D0), math.log(sigma)])
            starts.append((float(np.sum(along.solve(p0)[0] ** 2)), shift, p0))
        p0 = min(starts, key=lambda s: s[0])[2]
        p, cov, rms = along.fit(p0)
        if not np.all(np.isfinite(p)):
            return "the tip's profile along the axis did not settle"
        tc, sigma = float(p[0]), float(math.exp(p[2]))
        D = math.exp(p[1])
        rho = D * along.rho_per_d
        fit = (p, cov, rms, along, var_across)
        origin = origin + u * tc + n * (a0 + a1 * tc)
        direction = u + n * a1
        u = direction / np.linalg.norm(direction)
        if abs(tc) < 0.3 and attempt > 0:
            break
    assert fit is not None
    p, cov, rms, along, var_across = fit
    tip = origin
    _, coef = along.solve(p)
    var_along = float(cov[0, 0])
    n = np.array([-u[1], u[0]])
    cov_px = var_along * np.outer(u, u) + var_across * np.outer(n, n)
    moved = float(np.linalg.norm(tip - blob.tip_px))
    if not np.all(np.isfinite(tip)) or moved > 12.0 + 3.0 * sigma:
        return "the tip's profile along the axis did not settle"
    contrast = 0.5 * float(coef[1])
    y0, x0_ = int(np.clip(tip[1], 0, h - 1)), int(np.clip(tip[0], 0, w - 1))
    return TipFit(
        apex_px=tip, cov_px=cov_px, axis=u, vertex_px=tip - u * D, half_angle_rad=beta,
        end_radius_px=rho, blur_px=sigma, contrast=contrast, rms=rms,
        noise=_noise(gray[max(y0 - 24, 0): y0 + 25, max(x0_ - 24, 0): x0_ + 25]),
    )  # fmt: skip
