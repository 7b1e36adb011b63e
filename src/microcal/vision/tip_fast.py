"""The fast tip fit: a closed-form image of the tool's end, fitted by Gauss-Newton on a patch.

A detection within a few milliseconds on a 256 x 256 region, for every kind of tool:

- **Coarse.** The tool is found (:func:`~microcal.vision.tip_find.find_tool`) on the image
  halved in each direction (the mean of each 2 x 2 block): a quarter of the pixels, the same
  reasons when there is no tool.
- **Outline.** Near its end a tool is the wedge of :mod:`~microcal.vision.tip_image_model`:
  edges of half-angle ``beta`` about the axis touching the end's ellipse (``rho`` across the
  axis, ``k rho`` along it, ``k`` from the kind and the taper) centred on the tip point,
  cut by the chord through the points of contact. Each pixel's signed distance ``d`` to that
  outline is written in closed form: ``|x| cos beta - (t + D) sin beta`` beside the taper (its
  vertex ``D`` ahead of the tip point), the ellipse's first-order distance around the end.
- **Image.** A blurred straight edge is ``Phi(-d / s)``; so the tool's coverage is drawn as
  ``Phi(-d / s)`` with ``s^2 = sigma^2 + 1/12`` (the Gaussian blur and the pixel's width), the
  blur ``sigma = hypot(floor, a + g t)`` growing along a tool held at an angle; a blurred
  disc's half-level lies ``sigma^2 / (2 rho)`` inside its rim, which the end's distance takes
  in. Glass adds a second layer, its walls: the coverage less that of the outline shrunk by
  the wall's thickness (``GLASS_WALL`` of the local half-width), darker than the lumen. The
  image is a quadratic background less the layers times their darkness.
- **Fit.** The eight outline and blur parameters and the linear ones together, by
  Levenberg-Marquardt on a patch of some 300-700 pixels reaching 20 px behind the tip, from
  the lowest of a scan along the coarse axis; the layers' derivatives by the chain rule
  through ``d`` (the distance's own derivatives by differences), the blur's in closed form;
  the patch is drawn again once around the fitted tip when it moved.

The tip point's covariance is the fit's ``(J^T J)^-1 s^2`` (residual variance ``s^2``) times
how much neighbouring residuals agree (as in the image fit), times :data:`COVARIANCE_SCALE`,
plus the model's own error (:data:`MODEL_ERROR_PER_BLUR` times the blur) in quadrature: a
rule chosen on one set of rendered seeds and checked on another. Being a closed form and not
a rendering, it is an approximation of the tool's image: its figures on the population are
in ``docs/vision.md``.
"""

from __future__ import annotations

import functools
import math

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.special import ndtr

from .._validation import FloatArray
from .tip_find import ToolBlob, find_tool
from .tip_fit import TipFit, _end_ratio, _noise, neighbour_correlation_factor
from .tip_image_model import _window, glass_loss
from .tip_target import TipTarget

__all__ = ["COVARIANCE_SCALE", "MODEL_ERROR_PER_BLUR", "coarse_tool", "fast_tip_fit"]

#: The stated covariance is ``COVARIANCE_SCALE`` times the fit's, plus a model error of
#: ``MODEL_ERROR_PER_BLUR`` (glass, opaque) times the blur at the tip, px, in quadrature: the
#: closed form is an approximation of the tool's image, whose error grows with the blur.
#: Chosen on seeds 600_000 and up (``scripts/tip_covariance_rule.py``) so that the 95 %
#: ellipse holds 90-98 % of the errors in focus and one depth of field off; checked on the
#: seeds of ``scripts/tip_population.py``.
COVARIANCE_SCALE = 1.0
MODEL_ERROR_PER_BLUR = (0.20, 0.10)
#: How far behind the tip the patch reaches, px, and ahead of it (plus three blurs).
_BACK_PX = 20.0
_FRONT_PX = 4.0
#: Differences for the distance's derivatives in beta and log rho (the others in closed form).
_STEPS = np.array([0.0, 0.0, 0.0, 1e-4, 1e-3])
#: The scan along the coarse axis for the start, px from the coarse tip.
_SHIFTS = np.arange(-12.0, 12.5, 4.0)
#: Patches drawn at most, and how near the patch's tip the fitted one must stay, px.
_ATTEMPTS = 6
_STAY_PX = 2.0
_SQRT_2PI = math.sqrt(2.0 * math.pi)
_N_GEOM = 5
_N_NL = 7
#: The blur's least sigma (diffraction takes the rest), px.
_FLOOR_PX = 0.3
#: The end's front (ahead of the chord where the edges touch it) is drawn as a band as wide
#: as the tool there and this share of the front's length long: between its area's share
#: (pi / 4, right when blurred well beyond it) and all of it (right when sharp); measured
#: on the rendered population (seeds 0-11 of each row of ``scripts/tip_population.py``).
_FRONT_SHARE = 0.84


def _glass_tables() -> tuple[FloatArray, FloatArray, FloatArray]:
    """The glass's refractive darkness across a tube, blurred: a table over ``log w``
    (``w``: the half-width over the blur) and ``q = |x| / (hw + 4 s)``, with its derivatives
    along both, each (len(_LOG_W), len(_Q))."""
    xi = np.linspace(-1.0, 1.0, 601)
    loss = glass_loss(xi) * (xi[1] - xi[0])
    table = np.empty((_LOG_W.size, _Q.size))
    for i, w in enumerate(np.exp(_LOG_W)):
        # |x| in half-widths: q (hw + 4 s) / hw = q (1 + 4 / w)
        u = _Q[:, None] * (1.0 + 4.0 / w)
        table[i] = (np.exp(-0.5 * ((u - xi[None, :]) * w) ** 2) * (w / _SQRT_2PI)) @ loss
    d_logw = np.asarray(np.gradient(table, axis=0)) / (_LOG_W[1] - _LOG_W[0])
    d_q = np.asarray(np.gradient(table, axis=1)) / (_Q[1] - _Q[0])
    return table, d_logw, d_q


#: The glass table's grid: log of the half-width over the blur, and |x| / (hw + 4 s).
_LOG_W = np.linspace(math.log(0.05), math.log(60.0), 96)
_Q = np.linspace(0.0, 1.0, 241)


@functools.cache
def _table() -> FloatArray:
    """The glass tables stacked, (len(_LOG_W) * len(_Q), 3); built on first use."""
    stacked = np.stack(_glass_tables(), axis=-1).reshape(-1, 3)
    out: FloatArray = np.ascontiguousarray(stacked)
    return out


def _lookup(log_w: FloatArray, q: FloatArray, derivatives: bool) -> FloatArray:
    """The glass table (and its derivatives in log w and q, when asked), bilinear at
    (log w, q): (N, 1) or (N, 3)."""
    fi = (np.clip(log_w, _LOG_W[0], _LOG_W[-1]) - _LOG_W[0]) * (1.0 / (_LOG_W[1] - _LOG_W[0]))
    fj = np.clip(q, 0.0, 1.0) * (1.0 / (_Q[1] - _Q[0]))
    i = np.minimum(fi.astype(np.intp), _LOG_W.size - 2)
    j = np.minimum(fj.astype(np.intp), _Q.size - 2)
    a, b = (fi - i)[:, None], (fj - j)[:, None]
    at = i * _Q.size + j
    table = _table() if derivatives else _table()[:, :1]
    out: FloatArray = (1 - a) * ((1 - b) * table[at] + b * table[at + 1]) + a * (
        (1 - b) * table[at + _Q.size] + b * table[at + _Q.size + 1]
    )
    return out


def coarse_tool(gray: NDArray[np.float32]) -> ToolBlob | str:
    """:func:`~microcal.vision.tip_find.find_tool` on the image halved (2 x 2 means; its least
    lengths and areas halved too), in the whole image's pixels; the background's light is
    the halved image's."""
    h, w = gray.shape
    h2, w2 = h // 2, w // 2
    if h2 < 16 or w2 < 16:
        return find_tool(gray)
    small = cv2.resize(gray[: 2 * h2, : 2 * w2], (w2, h2), interpolation=cv2.INTER_AREA)
    blob = find_tool(small, scale=0.5)
    if isinstance(blob, str):
        return blob
    return ToolBlob(blob.tip_px * 2.0 + 0.5, blob.axis, blob.half_angle_rad, blob.darkness,
                    blob.noise, blob.background)  # fmt: skip


class _Patch:
    """The pixels of a patch and the closed-form image of the tool over them."""

    def __init__(self, gray: NDArray[np.float32], target: TipTarget, tip: FloatArray,
                 axis: FloatArray, beta: float, blur: float,
                 ahead: float = 0.0) -> None:  # fmt: skip
        front = _FRONT_PX + 3.0 * blur + ahead
        win = _window(gray.shape[:2], tip, axis, beta, blur, front, _BACK_PX)
        self.ok = win is not None  # a patch under 8 x 8 px inside the image: not fitted
        (x0, y0, x1, y1), mask = win if win is not None else ((0, 0, 0, 0), np.zeros((0, 0), bool))
        self.box = (x0, y0, x1, y1)
        self.mask = mask
        rows, cols = np.nonzero(mask)  # in the order boolean indexing takes them
        self.px = (cols + x0).astype(np.float64)
        self.py = (rows + y0).astype(np.float64)
        self.values = gray[y0:y1, x0:x1][mask].astype(np.float64)
        self.target = target
        self.glass = target.kind in ("pipette", "any")
        cx, cy = 0.5 * (x0 + x1 - 1), 0.5 * (y0 + y1 - 1)
        gx = (self.px - cx) / max(x1 - x0, 1)
        gy = (self.py - cy) / max(y1 - y0, 1)
        self.plane = np.column_stack([np.ones_like(gx), gx, gy, gx * gx, gx * gy, gy * gy])

    def layers(self, p: FloatArray, derivatives: bool) -> tuple[FloatArray, FloatArray | None]:
        """The darkness layers (L, N) and, when asked, their derivatives (L, N, 7)."""
        return self.tool_layers(p, derivatives)

    def shape(self, beta: float, rho: float) -> tuple[float, float, float]:
        """(D, front, hw_open): the vertex ahead of the tip point, where the end's front is
        cut and the half-width there, px, for the half-angle ``beta`` and end radius ``rho``."""
        k = _end_ratio(self.target, beta)
        tb = math.tan(beta)
        D = rho * math.sqrt(k * k + 1.0 / (tb * tb))
        tc = -k * k * rho * rho / D
        return D, tc - _FRONT_SHARE * (k * rho + tc), max((tc + D) * tb, 0.05)

    def tool_layers(self, p: FloatArray, derivatives: bool
                    ) -> tuple[FloatArray, FloatArray | None]:  # fmt: skip
        """The tool's layers, each the profile across the taper blurred times the cut at the
        end's front blurred along the axis: its coverage and, for glass, its refractive
        darkness; (L, N) and their derivatives (L, N, 7)."""
        c, sn = math.cos(p[2]), math.sin(p[2])
        dx, dy = self.px - p[0], self.py - p[1]
        t = dx * c + dy * sn
        X = dy * c - dx * sn
        x = np.abs(X)
        beta = float(np.clip(p[3], 0.005, 1.2))
        rho = math.exp(float(np.clip(p[4], -5.0, 4.0)))
        tb = math.tan(beta)
        D, front, hw_open = self.shape(beta, rho)
        behind = np.maximum(t, 0.0)
        defocus = p[5] + p[6] * behind
        s = np.sqrt(_FLOOR_PX**2 + defocus * defocus + 1.0 / 12.0)
        hw_taper = (t + D) * tb
        hw = np.maximum(hw_taper, hw_open)
        # along: the cut at the end's front, blurred
        za = (t - front) / s
        A = ndtr(za)
        # across: the tool's coverage, blurred, and for glass its refractive darkness
        zp, zm = (hw - x) / s, (-hw - x) / s
        cov = ndtr(zp) - ndtr(zm)
        span = hw + 4.0 * s
        if self.glass:
            looked = _lookup(np.log(hw / s), x / span, derivatives)
            loss = looked[:, 0]
            out = np.array([A * cov, A * loss])
        else:
            out = (A * cov)[None, :]
        if not derivatives:
            return out, None
        pa = np.exp(-0.5 * za * za) / _SQRT_2PI
        pp, pm = np.exp(-0.5 * zp * zp) / _SQRT_2PI, np.exp(-0.5 * zm * zm) / _SQRT_2PI
        # partial derivatives in t, |x|, hw, s and the front's place
        A_t, A_s, A_front = pa / s, -pa * za / s, -pa / s
        parts = [(cov, (-pp + pm) / s, (pp + pm) / s, (-pp * zp + pm * zm) / s)]
        if self.glass:
            l_logw, l_q = looked[:, 1], looked[:, 2]
            parts.append((loss, l_q / span, l_logw / hw - l_q * x / (span * span),
                          -l_logw / s - l_q * 4.0 * x / (span * span)))  # fmt: skip
        s_t = np.where(t > 0, defocus * p[6] / s, 0.0)
        wide = hw_taper > hw_open
        hw_t = np.where(wide, tb, 0.0)
        # beta and log rho move the vertex, the front and the half-width at the front
        h = 1e-6
        D_b, front_b, open_b = ((v2 - v1) / h for v2, v1 in zip(
            self.shape(beta + h, rho), (D, front, hw_open), strict=True))  # fmt: skip
        D_r, front_r, open_r = ((v2 - v1) / h for v2, v1 in zip(
            self.shape(beta, rho * math.exp(h)), (D, front, hw_open), strict=True))  # fmt: skip
        hw_b = np.where(wide, D_b * tb + (t + D) * (1.0 + tb * tb), open_b)
        hw_r = np.where(wide, D_r * tb, open_r)
        sx = np.where(X < 0, -1.0, 1.0)
        grads = []
        for B, B_x, B_hw, B_s in parts:
            L_s = A_s * B + A * B_s
            L_t = A_t * B + A * (B_hw * hw_t) + L_s * s_t
            L_x = A * B_x * sx
            g = np.empty((t.size, _N_NL))
            # t = (q - c).u, X = (q - c).n: dt/dc = -u, dX/dc = -n, dt/dangle = X, dX/dangle = -t
            g[:, 0] = -L_t * c + L_x * sn
            g[:, 1] = -L_t * sn - L_x * c
            g[:, 2] = L_t * X - L_x * t
            g[:, 3] = A_front * B * front_b + A * B_hw * hw_b
            g[:, 4] = A_front * B * front_r + A * B_hw * hw_r
            g[:, 5] = L_s * defocus / s
            g[:, 6] = L_s * defocus * behind / s
            grads.append(g)
        return out, np.array(grads)

    def design(self, layers: FloatArray) -> FloatArray:
        """The linear terms' columns: the background's quadratic and the layers' darkness."""
        return np.hstack([self.plane, -layers.T])


def _solve_linear(A: FloatArray, b: FloatArray) -> FloatArray:
    G = A.T @ A
    out: FloatArray = np.linalg.solve(G + 1e-10 * np.trace(G) * np.eye(len(G)), A.T @ b)
    return out


def _fit(patch: _Patch, p0: FloatArray, iterations: int = 30
         ) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """Levenberg-Marquardt over the nonlinear and linear parameters together: (p, coef,
    residuals, Jacobian at the solution)."""
    p = p0.copy()
    lay, dlay = patch.layers(p, True)
    A = patch.design(lay)
    coef = _solve_linear(A, patch.values)
    r = patch.values - A @ coef
    cost = float(r @ r)
    lam = 1e-3
    nb = patch.plane.shape[1]
    scale = np.array([1.0, 1.0, 0.05, 0.05, 0.3, 0.5, 0.03])

    def jac(dl: FloatArray | None, cf: FloatArray) -> FloatArray:
        assert dl is not None
        dimg = -np.einsum("lnk,l->nk", dl, cf[nb:])
        return np.hstack([dimg, A])

    J = jac(dlay, coef)
    for _ in range(iterations):
        H = J.T @ J
        gvec = J.T @ r
        diag = np.diag(H) + 1e-12
        accepted = False
        while lam < 1e8:
            step = np.linalg.solve(H + lam * np.diag(diag), gvec)
            step[:_N_NL] = np.clip(step[:_N_NL], -3 * scale, 3 * scale)
            q = p + step[:_N_NL]
            lay_q, _ = patch.layers(q, False)
            A_q = patch.design(lay_q)
            coef_q = coef + step[_N_NL:]
            r_q = patch.values - A_q @ coef_q
            c_q = float(r_q @ r_q)
            if c_q < cost:
                accepted = True
                moved_px = float(np.hypot(*step[:2]))
                gain = cost - c_q
                p, coef, r, cost = q, coef_q, r_q, c_q
                lam = max(lam / 5.0, 1e-7)
                break
            lam *= 6.0
        if not accepted:
            break
        lay, dlay = patch.layers(p, True)
        A = patch.design(lay)
        J = jac(dlay, coef)
        if moved_px < 1e-3 or (moved_px < 0.01 and gain < 1e-5 * cost):
            break
    return p, coef, r, J


def _correlation_factor(patch: _Patch, resid: FloatArray) -> float:
    """:func:`~microcal.vision.tip_fit.neighbour_correlation_factor` of the patch's pixels."""
    x0, y0, x1, y1 = patch.box
    field = np.full((y1 - y0, x1 - x0), np.nan)
    field[patch.mask] = resid
    return neighbour_correlation_factor(field)


def _start(patch: _Patch, tip: FloatArray, axis: FloatArray, beta: float, blur: float,
           shifts: FloatArray) -> FloatArray:  # fmt: skip
    """The lowest of a scan along the axis (the linear terms solved for each)."""
    angle = math.atan2(axis[1], axis[0])
    best = None
    for sft in shifts:
        c = tip + axis * sft
        p = np.array([c[0], c[1], angle, beta, math.log(0.8), blur, 0.02])
        lay, _ = patch.layers(p, False)
        A = patch.design(lay)
        r = patch.values - A @ _solve_linear(A, patch.values)
        cost = float(r @ r)
        if best is None or cost < best[0]:
            best = (cost, p)
    assert best is not None
    return best[1]


def fast_tip_fit(gray: NDArray[np.float32], blob: ToolBlob, target: TipTarget) -> TipFit | str:
    """The tip point by the closed-form image fitted around the coarse tip of ``blob``.

    Parameters
    ----------
    gray : (H, W) float32
    blob : ToolBlob
        The coarse tool (:func:`coarse_tool`).
    target : TipTarget

    Returns
    -------
    TipFit or str
        The fitted tip (whole-image pixels) or why the fit failed.
    """
    tip, axis = blob.tip_px.astype(np.float64), blob.axis.astype(np.float64)
    beta, blur = float(np.clip(blob.half_angle_rad, 0.03, 0.6)), 1.0
    patch = _Patch(gray, target, tip, axis, beta, blur)
    if not patch.ok or patch.values.size < 40:
        return "the tip is at the edge of the field"
    p = _start(patch, tip, axis, beta, blur, _SHIFTS)
    for _attempt in range(_ATTEMPTS):
        p, coef, r, J = _fit(patch, p)
        moved = float(np.hypot(*(p[:2] - tip)))
        if moved < _STAY_PX:
            break
        if _attempt == _ATTEMPTS - 1:
            return f"the fast fit did not settle (its tip still moved {moved:.1f} px)"
        # the tip is far from where the patch was drawn: draw it again around the fit,
        # reaching further ahead when the fit followed a faint end to the patch's front
        blur = float(math.hypot(_FLOOR_PX, p[5]))
        ahead = float(np.clip(-(p[:2] - tip) @ axis, 0.0, 16.0))
        tip, axis = p[:2].copy(), np.array([math.cos(p[2]), math.sin(p[2])])
        patch = _Patch(gray, target, tip, axis, float(np.clip(p[3], 0.03, 0.6)), blur, ahead)
        if not patch.ok or patch.values.size < 40:
            return "the tip is at the edge of the field"
    tip, axis = p[:2].copy(), np.array([math.cos(p[2]), math.sin(p[2])])
    blur = float(math.hypot(_FLOOR_PX, p[5]))
    n_px, m = r.size, J.shape[1]
    rss = float(r @ r)
    JTJ = J.T @ J
    try:
        cov_all = np.linalg.inv(JTJ + 1e-12 * np.trace(JTJ) * np.eye(m))
    except np.linalg.LinAlgError:
        return "the fast fit is degenerate (the tool's outline is not seen)"
    cov = cov_all[:2, :2] * rss / max(n_px - m, 1)
    cov = cov * _correlation_factor(patch, r) * COVARIANCE_SCALE
    model_px = MODEL_ERROR_PER_BLUR[0 if patch.glass else 1] * math.hypot(_FLOOR_PX, p[5])
    cov = cov + model_px**2 * np.eye(2)
    if not np.all(np.isfinite(cov)) or min(np.linalg.eigvalsh(cov)) <= 0:
        return "the fast fit is degenerate (the tool's outline is not seen)"
    beta_fit = float(np.clip(p[3], 0.005, 1.2))
    rho = math.exp(float(np.clip(p[4], -5.0, 4.0)))
    k = _end_ratio(target, beta_fit)
    D = rho * math.sqrt(k * k + 1.0 / math.tan(beta_fit) ** 2)
    nb = patch.plane.shape[1]
    level = float(coef[0])
    darkest = float(coef[nb]) + (max(float(coef[nb + 1]), 0.0) if patch.glass else 0.0)
    x0, y0, x1, y1 = patch.box
    return TipFit(
        apex_px=tip, cov_px=cov, axis=axis, vertex_px=tip - axis * D,
        half_angle_rad=beta_fit, end_radius_px=rho, blur_px=blur,
        contrast=darkest / max(abs(level), 1e-9), rms=math.sqrt(rss / n_px),
        noise=_noise(gray[y0:y1, x0:x1]),
    )  # fmt: skip
