"""Chessboard corners by a model of their picture, fitted to the pixels themselves.

The symmetry fit of :mod:`~microcal.vision.corner_refinement` compares grey levels sampled
between pixels (bilinear interpolation). When the picture is sharp (a blur of under a pixel,
as with a good microscope objective), interpolation cannot follow an edge between two
pixels, and the centre of symmetry it finds is drawn by a few hundredths of a pixel towards
or away from the pixel lattice, by an amount that depends on where the corner falls between
pixels (0.01-0.025 px on rendered boards at 0.7 px blur).

Here the picture of each corner is modelled as two straight edges crossing at the corner,
each blurred by a Gaussian (which also stands for the pixel's box):

``I(x) = a + b * erf(n1 . (x - c) / (sqrt(2) s)) * erf(n2 . (x - c) / (sqrt(2) s))``

with the edges' normals ``n1``, ``n2`` (angles free, so perspective and shear are followed),
the blur ``s``, the levels ``a`` and ``b``, and the corner ``c``; it is fitted to the pixels
of a window around the corner (Gaussian weights, Gauss-Newton with a little damping). The
model is evaluated at the pixels' own centres: nothing is interpolated. Where the crossing
of two blurred edges differs from the product of their profiles (edges far from
perpendicular), the difference is point-symmetric about the corner, as the picture is, and
does not move it.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.special import erf

from .._validation import FloatArray

__all__ = ["MAX_MODEL_SHIFT_PX", "MODEL_WINDOW_FRACTION", "fit_corner_model"]

#: The window's half-width as a fraction of the corner's spacing to its grid neighbours
#: (a marker circle, half a square across in its square, stays outside it).
MODEL_WINDOW_FRACTION = 0.35
#: A fit that moves a corner farther than this from its start, px, keeps the start.
MAX_MODEL_SHIFT_PX = 0.5
_ITERATIONS = 12
_SQRT2 = float(np.sqrt(2.0))
_CHUNK = 200


def fit_corner_model(
    gray: NDArray[np.float32],
    corners_px: FloatArray,
    axes_px: FloatArray,
    spacing_px: FloatArray,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Corners refined by fitting the model of two blurred edges to the pixels.

    Parameters
    ----------
    gray : (H, W) float32
    corners_px : (N, 2) float
        Corners within a few tenths of a pixel (a symmetry fit's).
    axes_px : (N, 2, 2) float
        Each corner's two grid directions in the image (along the board's rows and columns;
        any length): the edges run along them.
    spacing_px : (N,) float
        Each corner's spacing to its grid neighbours, px.

    Returns
    -------
    corners_px : (N, 2) float
        Refined (the start where ``ok`` is False).
    ok : (N,) bool
        The fit converged inside the image and moved the corner less than
        :data:`MAX_MODEL_SHIFT_PX`.
    """
    q = np.asarray(corners_px, dtype=np.float64)
    out = q.copy()
    ok = np.zeros(len(q), dtype=bool)
    if len(q) == 0:
        return out, ok
    half = np.maximum(2.0, MODEL_WINDOW_FRACTION * np.asarray(spacing_px, dtype=np.float64))
    reach = int(np.ceil(np.max(half)))
    h_img, w_img = gray.shape
    inside = (q[:, 0] - reach >= 0) & (q[:, 1] - reach >= 0) & \
        (q[:, 0] + reach + 1 < w_img) & (q[:, 1] + reach + 1 < h_img)  # fmt: skip
    oy, ox = np.mgrid[-reach : reach + 1, -reach : reach + 1]
    offsets = np.column_stack([ox.ravel(), oy.ravel()]).astype(np.float64)
    for start in range(0, len(q), _CHUNK):
        k = np.arange(start, min(start + _CHUNK, len(q)))
        k = k[inside[k]]
        if len(k) == 0:
            continue
        c, good = _fit(gray, q[k], np.asarray(axes_px, dtype=np.float64)[k], half[k], offsets)
        good &= np.linalg.norm(c - q[k], axis=1) < MAX_MODEL_SHIFT_PX
        out[k[good]] = c[good]
        ok[k[good]] = True
    return out, ok


def _fit(
    gray: NDArray[np.float32],
    q: FloatArray,
    axes: FloatArray,
    half: FloatArray,
    offsets: FloatArray,
) -> tuple[FloatArray, NDArray[np.bool_]]:
    """Gauss-Newton over (cx, cy, t1, t2, s, a, b) of K corners at once."""
    base = np.floor(q).astype(np.intp)
    px = base[:, None, :] + offsets[None].astype(np.intp)  # (K, M, 2) pixel centres
    values = gray[px[..., 1], px[..., 0]].astype(np.float64)
    xy = px.astype(np.float64)
    r2 = np.sum((xy - q[:, None, :]) ** 2, axis=2)
    sig_w = half[:, None] / 1.5
    w = np.exp(-r2 / (2.0 * sig_w**2)) * (r2 <= half[:, None] ** 2)
    # the edges' normals: perpendicular to the grid directions
    t1 = np.arctan2(axes[:, 0, 1], axes[:, 0, 0]) + 0.5 * np.pi
    t2 = np.arctan2(axes[:, 1, 1], axes[:, 1, 0]) + 0.5 * np.pi
    p = np.column_stack([q, t1, t2, np.full(len(q), 1.0), np.zeros(len(q)), np.zeros(len(q))])
    p[:, 5:] = _levels(p, xy, values, w)
    converged = np.zeros(len(q), dtype=bool)
    for _ in range(_ITERATIONS):
        model, J = _model(p, xy)
        r = values - model
        wJ = w[..., None] * J
        A = np.einsum("kmi,kmj->kij", wJ, J)
        g = np.einsum("kmi,km->ki", wJ, r)
        A += 1e-6 * np.eye(7) * np.trace(A, axis1=1, axis2=2)[:, None, None]
        try:
            step = np.linalg.solve(A, g[..., None])[..., 0]
        except np.linalg.LinAlgError:
            return q, np.zeros(len(q), dtype=bool)
        step[~np.all(np.isfinite(step), axis=1)] = 0.0
        step[:, :2] = np.clip(step[:, :2], -0.25, 0.25)
        step[:, 4] = np.clip(step[:, 4], -0.5 * p[:, 4], 0.5 * p[:, 4])
        p += step
        converged = np.abs(step[:, :2]).max(axis=1) < 1e-5
        if converged.all():
            break
    good = converged & np.all(np.isfinite(p), axis=1) & (p[:, 4] > 0.2) & (p[:, 4] < 0.5 * half)
    return p[:, :2], good


def _levels(p: FloatArray, xy: FloatArray, values: FloatArray, w: FloatArray) -> FloatArray:
    """The levels a, b (K, 2) by weighted least squares for the other parameters."""
    e = _edges(p, xy)[0]
    s0, s1, s2 = w.sum(axis=1), (w * e).sum(axis=1), (w * e * e).sum(axis=1)
    v0, v1 = (w * values).sum(axis=1), (w * e * values).sum(axis=1)
    det = s0 * s2 - s1**2
    det = np.where(det == 0, 1.0, det)
    return np.column_stack([(s2 * v0 - s1 * v1) / det, (s0 * v1 - s1 * v0) / det])


def _edges(p: FloatArray, xy: FloatArray) -> tuple[FloatArray, ...]:
    u = xy[..., 0] - p[:, 0, None]
    v = xy[..., 1] - p[:, 1, None]
    c1, s1 = np.cos(p[:, 2])[:, None], np.sin(p[:, 2])[:, None]
    c2, s2 = np.cos(p[:, 3])[:, None], np.sin(p[:, 3])[:, None]
    d1, d2 = c1 * u + s1 * v, c2 * u + s2 * v
    s = p[:, 4, None]
    e1, e2 = erf(d1 / (_SQRT2 * s)), erf(d2 / (_SQRT2 * s))
    return e1 * e2, e1, e2, d1, d2, u, v, c1, s1, c2, s2


def _model(p: FloatArray, xy: FloatArray) -> tuple[FloatArray, FloatArray]:
    """The model at the pixels (K, M) and its derivatives by the 7 parameters (K, M, 7)."""
    prod, e1, e2, d1, d2, u, v, c1, s1, c2, s2 = _edges(p, xy)
    s = p[:, 4, None]
    a, b = p[:, 5, None], p[:, 6, None]
    k = np.sqrt(2.0 / np.pi) / s
    g1, g2 = k * np.exp(-0.5 * (d1 / s) ** 2), k * np.exp(-0.5 * (d2 / s) ** 2)
    J = np.empty((*u.shape, 7))
    J[..., 0] = -b * (g1 * c1 * e2 + e1 * g2 * c2)
    J[..., 1] = -b * (g1 * s1 * e2 + e1 * g2 * s2)
    J[..., 2] = b * g1 * (-s1 * u + c1 * v) * e2
    J[..., 3] = b * e1 * g2 * (-s2 * u + c2 * v)
    J[..., 4] = -b * (g1 * d1 * e2 + e1 * g2 * d2) / s
    J[..., 5] = 1.0
    J[..., 6] = prod
    return a + b * prod, J
