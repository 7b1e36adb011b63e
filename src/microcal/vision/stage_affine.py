"""A microscope camera calibrated against its X-Y stage: the image-to-stage affine map,
pixel size, radial distortion and the focus axis's tilt, from a slide moved by known steps.

The slide's features (a dot grid with marker dots, or any target whose features are
numbered) are seen in views taken at known stage positions ``s_v`` (µm) and focus positions
``z_v`` (µm). A feature ``j`` at ``P_j`` on the slide (µm) is seen at

    y = B P_j + M s_v + g z_v + t,        q = c + r d(y / r)

with ``M`` (2 x 2, px per stage µm) the image's displacement per stage move (any affine
map: the stage's axes may be skewed and scaled), ``B`` the slide's picture (a similarity,
mirrored or not: square pixels see a square grid as a square grid; its scale is not trusted,
the stage is the ruler), ``g`` (px/µm) the image's drift per µm of focus,
``t`` a constant, ``c`` the image centre, ``r`` half the image diagonal and ``d`` the radial
distortion ``d(u) = u (1 + k1 |u|^2 + k2 |u|^4)`` (the convention of
:class:`~microcal.geometry.affine_camera.AffineCamera`). A linear estimate (no distortion)
starts a least-squares fit of the twelve parameters.

The results are in Micro-Manager's pixel-size-affine convention (``docs/conventions.md``):
the image-to-stage map ``A = -M^-1`` (its six numbers, translation 0), the pixel size
``sqrt(|det A|)``, and the focus axis as the field's travel over the sample per µm of focus
(``-A g``, stage µm per µm) with its angle to the optical axis.

Uncertainties: an error of a stage position moves every feature seen there together, so the
residuals are the features' own scatter (variance ``s²``, estimated within each stage
visit: views in a row, in the order given, at one stage position) plus a common shift per
visit and image axis (variance ``tau²``, estimated from the visits' mean residuals, with the
three parameters per image axis the model spends at that level taken off). The parameters'
covariance is ``(J'J)^-1 (s² J'J + tau² sum_c J_c' 1 1' J_c) (J'J)^-1``; each derived
figure's standard deviation is propagated from it to first order.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from .._validation import FloatArray
from ..errors import InputError
from ..json_value import JsonValue

__all__ = [
    "MIN_FEATURES",
    "MIN_VIEWS",
    "REJECT_PX",
    "ScopeCalibration",
    "SlideView",
    "fit_stage_affine",
    "follow_numbering",
]

#: Fewest views with the slide found: the stage's 2 x 2 map, the drift and the slide's
#: pose need views at three stage positions or more and at two focus positions or more.
MIN_VIEWS = 4
#: Fewest features a view must have to be used.
MIN_FEATURES = 6
#: A view whose features miss the stage's prediction by more than this (RMS, px; and ten
#: times the views' median) is left out: its slide was numbered wrongly.
REJECT_PX = 2.0
_N = 12  # parameters: M (4), B (2), g (2), t (2), k1, k2


@dataclass(frozen=True)
class SlideView:
    """The slide's features seen at one stage and focus position.

    Attributes
    ----------
    stage_um : (2,) float
        The X-Y stage's position, µm.
    focus_um : float
        The focus drive's position, µm.
    ids : (N,) int
        The features' numbers (rows of the slide's ``points_um()``).
    q_px : (N, 2) float
        Their pixel positions.
    """

    stage_um: FloatArray
    focus_um: float
    ids: NDArray[np.intp]
    q_px: FloatArray


@dataclass(frozen=True)
class ScopeCalibration:
    """A camera's calibration against its X-Y stage and focus drive (one objective).

    Lengths in µm, angles in degrees; every ``*_sd`` is the standard deviation of the value
    it follows. See the module docstring for the model and ``docs/conventions.md`` for the
    conventions.

    Attributes
    ----------
    affine_um : (2, 3) float
        Micro-Manager's pixel-size affine (``setPixelSizeAffine``'s six numbers are its rows):
        stage µm per pixel, translation 0.
    affine_sd_um : (2, 3) float
        Standard deviations of its entries.
    pixel_size_um, pixel_size_sd_um : float
        ``sqrt(|det A|)``.
    scale_um, scale_sd_um : (2,) float
        The stage length of one pixel along the image's x and y axes.
    rotation_deg, rotation_sd_deg : float
        Direction of the image's +x axis in the stage's frame (from stage +x towards +y).
    skew_deg, skew_sd_deg : float
        The image's y axis off perpendicular to its x axis, in the stage's frame.
    mirrored : bool
        True when the map reverses handedness (``det A < 0``: image y down, stage y up).
    distortion : (2,) float
        ``k1, k2`` in half image diagonals about the image centre.
    distortion_sd : (2,) float
    distortion_corner_px, distortion_corner_sd_px : float
        The distortion's displacement at the image's corner, px.
    drift_px_per_um : (2,) float
        The image's drift per µm of focus, px/µm.
    focus_axis : (2,) float
        The field's travel over the sample per µm of focus, in the stage's frame (µm/µm).
    focus_angle_deg, focus_angle_sd_deg : float
        The angle between the focus axis and the optical axis.
    dxdz, dydz : float
        The image's drift along the camera's x and y axes per µm of focus, in µm in the
        object per µm (``drift_px_per_um`` times the pixel sizes).
    slide_scale, slide_scale_sd : float
        The slide's pitch as measured by the stage over its nominal pitch.
    rms_px : float
        RMS of the features' residuals.
    views, features : int
        Views used and features in them.
    image_size_px : (int, int)
    rejected : tuple of (int, float)
        Views left out (their index in the views given, and their RMS miss, px): the slide's
        numbering in them disagrees with the stage's moves.
    params : (12,) float
        The fitted parameters (M row-major, B's a and b, g, t, k1, k2).
    cov : (12, 12) float
        Their covariance.
    """

    affine_um: FloatArray
    affine_sd_um: FloatArray
    pixel_size_um: float
    pixel_size_sd_um: float
    scale_um: FloatArray
    scale_sd_um: FloatArray
    rotation_deg: float
    rotation_sd_deg: float
    skew_deg: float
    skew_sd_deg: float
    mirrored: bool
    distortion: FloatArray
    distortion_sd: FloatArray
    distortion_corner_px: float
    distortion_corner_sd_px: float
    drift_px_per_um: FloatArray
    focus_axis: FloatArray
    focus_angle_deg: float
    focus_angle_sd_deg: float
    dxdz: float
    dydz: float
    slide_scale: float
    slide_scale_sd: float
    rms_px: float
    views: int
    features: int
    image_size_px: tuple[int, int]
    params: FloatArray
    cov: FloatArray
    rejected: tuple[tuple[int, float], ...] = ()
    slide_mirror: float = 1.0

    def predict_px(self, plane_um: FloatArray, stage_um: FloatArray, focus_um: float) -> FloatArray:
        """Where the fitted model sees the slide's points ``plane_um`` (N, 2 or 3) with the
        stage at ``stage_um`` and the focus at ``focus_um``, (N, 2) px."""
        P = np.asarray(plane_um, dtype=np.float64)[:, :2]
        w, h = self.image_size_px
        centre = np.array([(w - 1) / 2, (h - 1) / 2])
        n = len(P)
        s = np.tile(np.asarray(stage_um, dtype=np.float64), (n, 1))
        z = np.full(n, float(focus_um))
        return _model(self.params, P, s, z, centre, math.hypot(w, h) / 2, self.slide_mirror)

    @property
    def micromanager_affine(self) -> list[float]:
        """The six numbers ``setPixelSizeAffine`` takes: ``A`` row by row."""
        return [float(v) for v in self.affine_um.ravel()]

    def to_json(self) -> dict[str, JsonValue]:
        """The calibration's JSON object (one objective's set in a scope file)."""

        def floats(a: FloatArray) -> list[JsonValue]:
            return [float(v) for v in np.ravel(a)]

        return {
            "pixel_size_affine": floats(self.affine_um),
            "pixel_size_affine_sd": floats(self.affine_sd_um),
            "pixel_size_um": self.pixel_size_um,
            "pixel_size_sd_um": self.pixel_size_sd_um,
            "scale_um": floats(self.scale_um),
            "scale_sd_um": floats(self.scale_sd_um),
            "rotation_deg": self.rotation_deg,
            "rotation_sd_deg": self.rotation_sd_deg,
            "skew_deg": self.skew_deg,
            "skew_sd_deg": self.skew_sd_deg,
            "mirrored": self.mirrored,
            "distortion": {
                "model": "radial2",
                "k": floats(self.distortion),
                "k_sd": floats(self.distortion_sd),
                "corner_px": self.distortion_corner_px,
                "corner_sd_px": self.distortion_corner_sd_px,
            },
            "focus": {
                "drift_px_per_um": floats(self.drift_px_per_um),
                "axis_um_per_um": floats(self.focus_axis),
                "angle_deg": self.focus_angle_deg,
                "angle_sd_deg": self.focus_angle_sd_deg,
                "dxdz": self.dxdz,
                "dydz": self.dydz,
            },
            "slide_scale": self.slide_scale,
            "slide_scale_sd": self.slide_scale_sd,
            "rms_px": self.rms_px,
            "views": self.views,
            "features": self.features,
            "rejected_views": [int(k) for k, _ in self.rejected],
            "image_size_px": [int(v) for v in self.image_size_px],
        }


def follow_numbering(
    gray: NDArray[np.float32], ids: NDArray[np.intp], q_px: FloatArray, *, tolerance: float = 0.3
) -> tuple[NDArray[np.intp], FloatArray]:
    """The dots of a frame numbered from another frame of the same slide position.

    A defocused frame may not resolve the marker dots' holes, but its dots lie within a pixel
    or two of where a focused frame at the same stage position saw them: each dot found
    (:func:`~microcal.vision.marker_grid.find_lattice_dots`) takes the number of the focused
    frame's dot within ``tolerance`` pitches of it.

    Parameters
    ----------
    gray : (H, W) float32
        The frame to number.
    ids, q_px : (N,) int, (N, 2) float
        The numbered frame's features (N >= 2).

    Returns
    -------
    ids, q_px
        The frame's dots that took a number (empty when none did, or no lattice was found).
    """
    from .marker_grid import find_lattice_dots

    empty = (np.zeros(0, dtype=np.intp), np.zeros((0, 2)))
    ref = np.asarray(q_px, dtype=np.float64).reshape(-1, 2)
    if len(ref) < 2:
        return empty
    dots = find_lattice_dots(gray)
    if dots.reason:
        return empty
    gap = np.linalg.norm(ref[:, None, :] - ref[None, :, :], axis=2)
    np.fill_diagonal(gap, np.inf)
    pitch = float(np.median(gap.min(axis=1)))
    dist = np.linalg.norm(dots.q_px[:, None, :] - ref[None, :, :], axis=2)
    nearest = dist.argmin(axis=1)
    ok = dist[np.arange(len(nearest)), nearest] < tolerance * pitch
    taken = np.asarray(ids)[nearest[ok]]
    unique, counts = np.unique(taken, return_counts=True)
    once = np.isin(taken, unique[counts == 1])
    order = np.argsort(taken[once])
    return taken[once][order].astype(np.intp), dots.q_px[ok][once][order]


def _stack(
    views: Sequence[SlideView], plane_um: FloatArray
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray, NDArray[np.intp]]:
    """Features of the usable views: slide points (n, 2), stage (n, 2), focus (n,), pixels
    (n, 2) and the view of each (n,)."""
    used = [v for v in views if len(v.ids) >= MIN_FEATURES]
    if len(used) < MIN_VIEWS:
        raise InputError(
            f"stage calibration: the slide was found in {len(used)} views with "
            f"{MIN_FEATURES} features or more; it needs {MIN_VIEWS} or more"
        )
    P = np.concatenate([plane_um[np.asarray(v.ids)] for v in used])
    s = np.concatenate([np.tile(np.asarray(v.stage_um, float), (len(v.ids), 1)) for v in used])
    z = np.concatenate([np.full(len(v.ids), float(v.focus_um)) for v in used])
    q = np.concatenate([np.asarray(v.q_px, float).reshape(-1, 2) for v in used])
    which = np.concatenate([np.full(len(v.ids), k) for k, v in enumerate(used)])
    stages = np.array([np.asarray(v.stage_um, float) for v in used])
    if np.linalg.matrix_rank(stages - stages.mean(axis=0), tol=1e-6) < 2:
        raise InputError(
            "stage calibration: the stage positions lie on one line; move the stage along "
            "both of its axes"
        )
    if np.ptp([v.focus_um for v in used]) <= 0:
        raise InputError(
            "stage calibration: every view is at one focus position; step the focus to "
            "measure the focus axis"
        )
    return P, s, z, q, which


def _slide_map(p: FloatArray, mirror: float) -> FloatArray:
    """``B``: the slide's picture, a similarity (times ``diag(1, mirror)``), (2, 2) px/µm."""
    out: FloatArray = np.array([[p[4], -p[5] * mirror], [p[5], p[4] * mirror]])
    return out


def _model(
    p: FloatArray, P: FloatArray, s: FloatArray, z: FloatArray, centre: FloatArray, r: float,
    mirror: float,
) -> FloatArray:  # fmt: skip
    M = p[:4].reshape(2, 2)
    y = P @ _slide_map(p, mirror).T + s @ M.T + np.outer(z, p[6:8]) + p[8:10]
    u = y / r
    rho2 = np.sum(u * u, axis=1, keepdims=True)
    out: FloatArray = centre + r * u * (1.0 + p[10] * rho2 + p[11] * rho2 * rho2)
    return out


def _linear_start(
    P: FloatArray, s: FloatArray, z: FloatArray, y: FloatArray
) -> tuple[FloatArray, float]:
    """Parameters without distortion, by linear least squares (``B`` free, then the
    similarity nearest it), and whether the slide's picture is mirrored (-1) or not (1)."""
    X = np.column_stack([P, s, z, np.ones(len(z))])  # B (2), M (2), g, t per image axis
    coef, *_ = np.linalg.lstsq(X, y, rcond=None)
    B, M, g, t = coef[0:2].T, coef[2:4].T, coef[4], coef[5]
    mirror = -1.0 if np.linalg.det(B) < 0 else 1.0
    Bm = B @ np.diag([1.0, mirror])
    a, b = (Bm[0, 0] + Bm[1, 1]) / 2, (Bm[1, 0] - Bm[0, 1]) / 2
    return np.concatenate([M.ravel(), [a, b], g, t, [0.0, 0.0]]), mirror


def _view_misses(
    P: FloatArray, s: FloatArray, z: FloatArray, y: FloatArray, which: NDArray[np.intp],
    trials: int = 300,
) -> FloatArray:  # fmt: skip
    """Each view's RMS miss of the linear model fitted to the views that agree best (a view
    whose slide was numbered wrongly misses by pitches): the fit of random sets of views with
    the least median miss, px, (V,)."""
    n_views = int(which.max()) + 1
    X = np.column_stack([P, s, z, np.ones(len(z))])
    count = np.bincount(which, minlength=n_views)

    def misses(rows: NDArray[np.bool_]) -> FloatArray:
        coef, *_ = np.linalg.lstsq(X[rows], y[rows], rcond=None)
        e = X @ coef - y
        out: FloatArray = np.sqrt(np.bincount(which, np.sum(e * e, axis=1), n_views) / count)
        return out

    def score(m: FloatArray) -> tuple[int, float]:
        return int(np.count_nonzero(m <= REJECT_PX)), -float(np.median(m))

    best = misses(np.ones(len(z), dtype=bool))
    if n_views <= MIN_VIEWS:
        return best
    rng = np.random.default_rng(0)
    for _ in range(trials):  # the largest set of views that agree (views misnumbered alike
        pick = rng.choice(n_views, size=MIN_VIEWS, replace=False)  # agree only among
        rows = np.isin(which, pick)  # themselves, at one stage position)
        if np.ptp(z[rows]) <= 0 or np.linalg.matrix_rank(s[rows] - s[rows].mean(0), 1e-6) < 2:
            continue
        m = misses(rows)
        if score(m) > score(best):
            best = m
    good = best <= max(REJECT_PX, 10.0 * float(np.median(best[best <= REJECT_PX])))  \
        if np.any(best <= REJECT_PX) else best <= np.inf  # fmt: skip
    return misses(np.isin(which, np.flatnonzero(good)))


def _visits(s: FloatArray) -> NDArray[np.intp]:
    """Each feature's stage visit: features in a row (views in the order taken) at one stage
    position share a visit; the stage moved between visits, (n,)."""
    moved = np.any(np.abs(np.diff(s, axis=0)) > 1e-6, axis=1)
    return np.concatenate([[0], np.cumsum(moved)]).astype(np.intp)


def _jacobian(f: Callable[[FloatArray], FloatArray], p: FloatArray) -> FloatArray:
    """Central differences of a derived figure ``f`` (k,) in the parameters, (k, 12)."""
    base = np.atleast_1d(f(p))
    J = np.zeros((base.size, p.size))
    for i in range(p.size):
        h = 1e-6 * max(abs(p[i]), 1e-3)
        up, down = p.copy(), p.copy()
        up[i] += h
        down[i] -= h
        J[:, i] = (np.atleast_1d(f(up)) - np.atleast_1d(f(down))) / (2 * h)
    return J


def _sd(f: Callable[[FloatArray], FloatArray], p: FloatArray, cov: FloatArray) -> FloatArray:
    J = _jacobian(f, p)
    out: FloatArray = np.sqrt(np.maximum(np.einsum("ij,jk,ik->i", J, cov, J), 0.0))
    return out


def _affine(p: FloatArray) -> FloatArray:
    inverse = np.linalg.inv(np.asarray(p[:4], dtype=np.float64).reshape(2, 2))
    out: FloatArray = -np.asarray(inverse, dtype=np.float64)
    return out


def _figures(p: FloatArray, r: float) -> FloatArray:
    """Derived figures: pixel size, scale x, scale y, rotation, skew (deg), corner
    distortion (px), focus angle (deg), slide scale, focus axis x, y."""
    A = _affine(p)
    ax, ay = A[:, 0], A[:, 1]
    rot = math.degrees(math.atan2(ax[1], ax[0]))
    cross = ax[0] * ay[1] - ax[1] * ay[0]
    between = math.degrees(math.atan2(abs(cross), float(ax @ ay)))
    axis = -A @ p[6:8]
    return np.array([
        math.sqrt(abs(np.linalg.det(A))), np.linalg.norm(ax), np.linalg.norm(ay), rot,
        90.0 - between, r * (p[10] + p[11]),
        math.degrees(math.atan(float(np.linalg.norm(axis)))), _slide_scale(p),
        axis[0], axis[1],
    ])  # fmt: skip


def _slide_scale(p: FloatArray) -> float:
    """The slide's pitch measured by the stage over its nominal pitch."""
    return math.sqrt((p[4] ** 2 + p[5] ** 2) / abs(np.linalg.det(p[:4].reshape(2, 2))))


def fit_stage_affine(
    views: Sequence[SlideView], plane_um: FloatArray, image_size_px: tuple[int, int]
) -> ScopeCalibration:
    """Fit the camera's map to the stage, its distortion and the focus axis to a slide's views.

    Parameters
    ----------
    views : sequence of SlideView
        Views at three stage positions or more (not on one line) and two focus positions
        or more, in the order they were taken (views in a row at one stage position share
        the stage's error of position); views with fewer than :data:`MIN_FEATURES` features
        are left out.
    plane_um : (F, 2) or (F, 3) float
        The slide's feature positions (``target.points_um()``), µm.
    image_size_px : (int, int)
        The image's width and height.

    Returns
    -------
    ScopeCalibration

    Raises
    ------
    InputError
        Too few usable views, stage positions on one line, or a single focus position (one
        line each).
    """
    plane = np.asarray(plane_um, dtype=np.float64)[:, :2]
    w, h = image_size_px
    centre = np.array([(w - 1) / 2, (h - 1) / 2])
    r = math.hypot(w, h) / 2
    index = [k for k, v in enumerate(views) if len(v.ids) >= MIN_FEATURES]
    P, s, z, q, which = _stack([views[k] for k in index], plane)
    miss = _view_misses(P, s, z, q - centre, which)
    bad = miss > REJECT_PX
    rejected = [(index[k], float(miss[k])) for k in np.flatnonzero(bad)]
    used = [views[k] for j, k in enumerate(index) if not bad[j]]
    if len(used) < MIN_VIEWS:
        raise InputError(
            f"stage calibration: the slide's numbering agrees with the stage's moves in "
            f"{len(used)} of {len(index)} views; it needs {MIN_VIEWS} or more (bring the "
            "slide's marker dots nearer the field's centre, or step the stage less)"
        )
    P, s, z, q, which = _stack(used, plane)
    start, mirror = _linear_start(P, s, z, q - centre)

    def residuals(p: FloatArray) -> FloatArray:
        out: FloatArray = (_model(p, P, s, z, centre, r, mirror) - q).ravel()
        return out

    sol = least_squares(residuals, start, method="lm", x_scale="jac")
    p = sol.x
    res = residuals(p)
    J = sol.jac
    n = res.size
    JtJ_inv = np.linalg.pinv(J.T @ J)
    # An error of a stage position moves every feature seen there alike: each visit's common
    # shift (per image axis) is a random effect of variance tau2 besides the features' own
    # scatter s2 (estimated within the visits).
    position = _visits(s)
    n_pos = int(position.max()) + 1
    key = 2 * np.repeat(position, 2) + np.tile([0, 1], len(z))
    counts = np.bincount(key, minlength=2 * n_pos).astype(float)
    means = np.bincount(key, res, minlength=2 * n_pos) / np.maximum(counts, 1)
    within = res - means[key]
    s2 = float(within @ within) / max(n - 2 * n_pos - _N, 1)
    # the model takes up three parameters per image axis at the positions' level (M's row, t)
    spread = float(np.sum(means**2 - s2 / np.maximum(counts, 1)))
    tau2 = max(spread / max(2 * n_pos - 6, 1), 0.0)
    summed = np.zeros((2 * n_pos, _N))
    np.add.at(summed, key, J)
    meat = s2 * (J.T @ J) + tau2 * (summed.T @ summed)
    cov = JtJ_inv @ meat @ JtJ_inv

    fig = _figures(p, r)
    fig_sd = _sd(lambda x: _figures(x, r), p, cov)
    A = _affine(p)
    A_sd = _sd(lambda x: _affine(x).ravel(), p, cov).reshape(2, 2)
    ps = fig[0]
    return ScopeCalibration(
        affine_um=np.column_stack([A, np.zeros(2)]),
        affine_sd_um=np.column_stack([A_sd, np.zeros(2)]),
        pixel_size_um=float(ps),
        pixel_size_sd_um=float(fig_sd[0]),
        scale_um=fig[1:3].copy(),
        scale_sd_um=fig_sd[1:3].copy(),
        rotation_deg=float(fig[3]),
        rotation_sd_deg=float(fig_sd[3]),
        skew_deg=float(fig[4]),
        skew_sd_deg=float(fig_sd[4]),
        mirrored=bool(np.linalg.det(A) < 0),
        distortion=p[10:12].copy(),
        distortion_sd=np.sqrt(np.diag(cov)[10:12]),
        distortion_corner_px=float(fig[5]),
        distortion_corner_sd_px=float(fig_sd[5]),
        drift_px_per_um=p[6:8].copy(),
        focus_axis=fig[8:10].copy(),
        focus_angle_deg=float(fig[6]),
        focus_angle_sd_deg=float(fig_sd[6]),
        dxdz=float(p[6] * fig[1]),
        dydz=float(p[7] * fig[2]),
        slide_scale=float(fig[7]),
        slide_scale_sd=float(fig_sd[7]),
        rms_px=float(np.sqrt(np.mean(res.reshape(-1, 2) ** 2) * 2)),
        views=int(which.max()) + 1,
        features=len(z),
        image_size_px=(int(w), int(h)),
        params=p,
        cov=cov,
        rejected=tuple(rejected),
        slide_mirror=mirror,
    )
