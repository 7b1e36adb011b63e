"""Field curvature: the focal surface over the field, from each region's sharpest focus.

A focus sweep over a flat slide gives, in each region of a grid over the image, a sharpness
curve whose peak is where that region is in focus (:func:`region_sharpness`: the mean squared
intensity gradient over the squared mean intensity). A parabola fitted to the logarithm of
the sharpness around its largest value gives the peak with its standard deviation. The
peaks are then fitted by ``z(x, y) = z0 + a u + b v + c (u² + v²)`` over the image's
coordinates ``(u, v)`` in half image diagonals from the centre (weighted by the peaks'
variances): the plane ``a, b`` is the slide's tilt, ``c`` the sag of the focal surface at the
image's corner (field curvature), µm.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray

from .._validation import FloatArray
from ..errors import InputError
from ..json_value import JsonValue

__all__ = ["FieldCurvature", "fit_field_curvature", "region_sharpness"]


def region_sharpness(image: NDArray[np.generic], regions: int = 5) -> FloatArray:
    """Each region's sharpness (mean squared gradient over squared mean intensity), (R, R),
    rows down the image."""
    gray = np.asarray(image, dtype=np.float32)
    if gray.ndim == 3:
        gray = gray.mean(axis=2).astype(np.float32)
    gx = cv2.Sobel(gray, cv2.CV_32F, 1, 0, ksize=3)
    gy = cv2.Sobel(gray, cv2.CV_32F, 0, 1, ksize=3)
    g2 = gx * gx + gy * gy
    h, w = gray.shape
    ys = np.linspace(0, h, regions + 1).astype(int)
    xs = np.linspace(0, w, regions + 1).astype(int)
    out = np.zeros((regions, regions))
    for i in range(regions):
        for j in range(regions):
            box = (slice(ys[i], ys[i + 1]), slice(xs[j], xs[j + 1]))
            mean = float(gray[box].mean())
            out[i, j] = float(g2[box].mean()) / max(mean * mean, 1e-12)
    return out


@dataclass(frozen=True)
class FieldCurvature:
    """The focal surface over the field (µm of focus; half image diagonals across).

    Attributes
    ----------
    corner_um, corner_sd_um : float
        The focal surface's sag at the image's corner (positive: the corners come into focus
        at a larger focus position than the centre).
    centre_um : float
        The focus position at which the image's centre is sharpest.
    tilt_um : (2,) float
        The focal plane's slope along the image's x and y, µm per half diagonal (the slide's
        tilt).
    peaks_um, peaks_sd_um : (R, R) float
        Each region's sharpest focus (NaN where the sweep did not bracket it).
    rms_um : float
        RMS of the peaks about the fitted surface.
    """

    corner_um: float
    corner_sd_um: float
    centre_um: float
    tilt_um: FloatArray
    peaks_um: FloatArray
    peaks_sd_um: FloatArray
    rms_um: float

    def to_json(self) -> dict[str, JsonValue]:
        """The JSON object of a scope file's ``field_curvature``."""

        def rows(a: FloatArray) -> list[JsonValue]:
            return [[None if not np.isfinite(v) else float(v) for v in r] for r in a]

        return {
            "corner_um": self.corner_um,
            "corner_sd_um": self.corner_sd_um,
            "centre_um": self.centre_um,
            "tilt_um": [float(v) for v in self.tilt_um],
            "peaks_um": rows(self.peaks_um),
            "peaks_sd_um": rows(self.peaks_sd_um),
            "rms_um": self.rms_um,
        }


def _peak(z: FloatArray, s: FloatArray) -> tuple[float, float]:
    """The sharpest focus of one region and its SD, from a parabola through the logarithm of
    the sharpness at the five positions around its largest value; NaN when not bracketed."""
    k = int(np.argmax(s))
    if k == 0 or k == len(s) - 1:
        return np.nan, np.nan
    lo, hi = max(0, k - 2), min(len(s), k + 3)
    zz, ll = z[lo:hi], np.log(np.maximum(s[lo:hi], 1e-300))
    X = np.column_stack([zz**2, zz, np.ones_like(zz)])
    coef, *_ = np.linalg.lstsq(X, ll, rcond=None)
    a, b = coef[0], coef[1]
    if a >= 0:
        return np.nan, np.nan
    zp = -b / (2 * a)
    if not zz[0] <= zp <= zz[-1]:
        return np.nan, np.nan
    dof = len(zz) - 3
    res = ll - X @ coef
    s2 = float(res @ res) / dof if dof > 0 else 0.0
    cov = s2 * np.linalg.pinv(X.T @ X)
    grad = np.array([b / (2 * a * a), -1 / (2 * a), 0.0])
    sd = float(np.sqrt(max(grad @ cov @ grad, 0.0)))
    step = float(np.median(np.diff(z)))
    return float(zp), max(sd, 0.02 * step)  # no better than a fiftieth of a step


def fit_field_curvature(focus_um: FloatArray, sharpness: FloatArray) -> FieldCurvature:
    """Fit the focal surface to a focus sweep's region sharpness.

    Parameters
    ----------
    focus_um : (N,) float
        The sweep's focus positions, increasing.
    sharpness : (N, R, R) float
        :func:`region_sharpness` of each frame.

    Raises
    ------
    InputError
        Fewer than five focus positions, or fewer than five regions whose sharpest focus the
        sweep brackets (one line).
    """
    z = np.asarray(focus_um, dtype=np.float64)
    sh = np.asarray(sharpness, dtype=np.float64)
    if len(z) < 5 or sh.shape[0] != len(z) or np.any(np.diff(z) <= 0):
        raise InputError(
            "field curvature: expected five increasing focus positions or more, each with "
            "its regions' sharpness"
        )
    n = sh.shape[1]
    peaks = np.full((n, n), np.nan)
    sds = np.full((n, n), np.nan)
    for i in range(n):
        for j in range(n):
            peaks[i, j], sds[i, j] = _peak(z, sh[:, i, j])
    ok = np.isfinite(peaks)
    if np.count_nonzero(ok) < 5:
        raise InputError(
            f"field curvature: the sweep brackets the sharpest focus of {np.count_nonzero(ok)} "
            f"of {n * n} regions; it needs 5 (sweep wider, from {z[0]:.2f} to {z[-1]:.2f} µm now)"
        )
    c = (np.arange(n) + 0.5) / n * 2 - 1  # region centres, -1..1 across the image
    half = np.sqrt(2.0)  # a square grid's corner at (1, 1) is one half diagonal
    v, u = np.meshgrid(c / half, c / half, indexing="ij")
    X = np.column_stack([np.ones(ok.sum()), u[ok], v[ok], u[ok] ** 2 + v[ok] ** 2])
    w = 1.0 / sds[ok]
    coef, *_ = np.linalg.lstsq(X * w[:, None], peaks[ok] * w, rcond=None)
    res = (X @ coef - peaks[ok]) * w
    dof = max(len(res) - 4, 1)
    chi2 = max(float(res @ res) / dof, 1.0)
    cov = chi2 * np.linalg.pinv((X * w[:, None]).T @ (X * w[:, None]))
    rms = float(np.sqrt(np.mean((X @ coef - peaks[ok]) ** 2)))
    return FieldCurvature(
        corner_um=float(coef[3]),
        corner_sd_um=float(np.sqrt(cov[3, 3])),
        centre_um=float(coef[0]),
        tilt_um=coef[1:3].copy(),
        peaks_um=peaks,
        peaks_sd_um=sds,
        rms_um=rms,
    )
