"""Lens models for one camera, and the choice between them by held-out error.

The models are OpenCV's, nested from the simplest to the richest (:data:`LENS_MODELS`):

| name | free distortion terms | coefficients stored |
| --- | --- | --- |
| ``radial1`` | k1 | 5 |
| ``radial2`` | k1, k2 | 5 |
| ``radial2-tangential`` | k1, k2, p1, p2 | 5 |
| ``radial3-tangential`` | k1, k2, k3, p1, p2 (OpenCV's default) | 5 |
| ``rational`` | + k4, k5, k6 | 8 |
| ``thin-prism`` | + s1, s2, s3, s4 | 12 |
| ``tilted`` | + tau_x, tau_y | 14 |

A richer model always fits the views it was fitted to at least as well, so the training RMS
cannot choose. :func:`choose_lens_model` fits each model to all views but a fold and measures
the held-out views (their board pose solved with the fitted intrinsics, the intrinsics not
refitted), over interleaved folds. Climbing the ladder, a richer model replaces the one kept
so far only when it predicts the held-out views better beyond chance: the views' paired
log-ratio of their squared errors exceeds :data:`SIGNIFICANCE` standard errors and
``log(1 +`` :data:`HELD_OUT_TOLERANCE` ``)`` (log-ratios, so that a view far outside the
others' reach, which every model extrapolates badly, does not decide). The held-out RMS
reported is that of a typical view: the square root of the views' geometric mean squared
error. The climb stops after :data:`STOP_AFTER`
models in a row that are not better. A richer model is never kept when a simpler one
predicts the held-out views as well or better.

Narrow-field (microscope) cameras keep the one constraint that makes them well posed: below
:data:`NARROW_FIELD_DEG` of diagonal field, the terms beyond k1 trade off with the principal
point and the focal length, and only ``radial1`` is offered.
"""

from __future__ import annotations

import contextlib
import re
from collections.abc import Sequence
from dataclasses import dataclass, field

import cv2
import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError, InputError

__all__ = [
    "HELD_OUT_TOLERANCE",
    "LENS_MODELS",
    "NARROW_FIELD_DEG",
    "LensModel",
    "LensModelChoice",
    "MonoFit",
    "choose_lens_model",
    "dist_of_length",
    "field_of_view_deg",
    "fit_camera",
    "lens_model",
    "opencv_reason",
    "predicts_better",
]

_KEEP_ZERO = cv2.CALIB_FIX_K4 | cv2.CALIB_FIX_K5 | cv2.CALIB_FIX_K6


@dataclass(frozen=True)
class LensModel:
    """One of OpenCV's distortion models, as calibration flags.

    Attributes
    ----------
    name : str
    terms : tuple of str
        The free distortion coefficients.
    flags : int
        ``cv2.calibrateCamera`` flags that leave exactly those free.
    n_coefficients : int
        Length of the distortion vector the model is stored with (5, 8, 12 or 14).
    """

    name: str
    terms: tuple[str, ...]
    flags: int
    n_coefficients: int

    @property
    def n_free(self) -> int:
        """Number of free distortion terms."""
        return len(self.terms)


_RADIAL = ("k1", "k2", "k3")
_TANGENTIAL = ("p1", "p2")
#: The models, simplest first; each one's free terms include the previous one's.
LENS_MODELS: tuple[LensModel, ...] = (
    LensModel(
        "radial1",
        ("k1",),
        cv2.CALIB_FIX_K2 | cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST | _KEEP_ZERO,
        5,
    ),
    LensModel(
        "radial2", _RADIAL[:2], cv2.CALIB_FIX_K3 | cv2.CALIB_ZERO_TANGENT_DIST | _KEEP_ZERO, 5
    ),
    LensModel("radial2-tangential", _RADIAL[:2] + _TANGENTIAL, cv2.CALIB_FIX_K3 | _KEEP_ZERO, 5),
    LensModel("radial3-tangential", _RADIAL + _TANGENTIAL, _KEEP_ZERO, 5),
    LensModel("rational", _RADIAL + _TANGENTIAL + ("k4", "k5", "k6"), cv2.CALIB_RATIONAL_MODEL, 8),
    LensModel(
        "thin-prism",
        _RADIAL + _TANGENTIAL + ("k4", "k5", "k6", "s1", "s2", "s3", "s4"),
        cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL,
        12,
    ),
    LensModel(
        "tilted",
        _RADIAL + _TANGENTIAL + ("k4", "k5", "k6", "s1", "s2", "s3", "s4", "tau_x", "tau_y"),
        cv2.CALIB_RATIONAL_MODEL | cv2.CALIB_THIN_PRISM_MODEL | cv2.CALIB_TILTED_MODEL,
        14,
    ),
)

#: A richer model must lower the simpler one's held-out squared errors by this fraction at
#: least (geometric mean over the views), ...
HELD_OUT_TOLERANCE = 0.02
#: ... and by this many standard errors of the views' paired differences.
SIGNIFICANCE = 2.0
#: Below this diagonal field of view (degrees) a camera is narrow-field: k1 only.
NARROW_FIELD_DEG = 10.0
#: Folds of the cross-validation (fewer when there are fewer views).
FOLDS = 5
#: Views needed to compare models by held-out error.
MIN_VIEWS_TO_CHOOSE = 4
#: The ladder is climbed until this many models in a row are not better than the one kept.
STOP_AFTER = 2

_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)


def dist_of_length(dist: object, n: int) -> FloatArray:
    """A distortion vector cut or zero-padded to ``n`` coefficients (OpenCV's order), (n,)."""
    flat = np.asarray(dist, dtype=np.float64).ravel()[:n]
    out = np.zeros(n)
    out[: flat.size] = flat
    return out


def opencv_reason(exc: Exception) -> str:
    """The readable part of an OpenCV error ("Principal point must be within the image")."""
    text = str(exc).strip().splitlines()[-1] if str(exc).strip() else type(exc).__name__
    m = re.search(r"error: \([^)]*\) (.*?)(?: in function .*)?$", text)
    return m.group(1).strip() if m else text


def lens_model(name: str) -> LensModel:
    """The model called ``name``.

    Raises
    ------
    InputError
        ``name`` is not one of :data:`LENS_MODELS` (the message lists them).
    """
    for model in LENS_MODELS:
        if model.name == name:
            return model
    known = ", ".join(m.name for m in LENS_MODELS)
    raise InputError(f"lens model {name!r}: expected auto or one of {known}")


@dataclass
class MonoFit:
    """One camera fitted with one lens model.

    Attributes
    ----------
    model : LensModel
    rms_px : float
        RMS reprojection error over all points of all views, px.
    K : (3, 3) float
    dist : (n_coefficients,) float
    rvecs, tvecs : list of (3,) float
        The board's pose in the camera frame, per view (µm).
    per_view_rms_px : (V,) float
    std_intrinsics : (4 + n_coefficients,) float
        OpenCV's standard deviations: fx, fy, cx, cy then the distortion coefficients.
    """

    model: LensModel
    rms_px: float
    K: FloatArray
    dist: FloatArray
    rvecs: list[FloatArray]
    tvecs: list[FloatArray]
    per_view_rms_px: FloatArray
    std_intrinsics: FloatArray


def fit_camera(
    object_points: Sequence[FloatArray],
    image_points: Sequence[FloatArray],
    size: tuple[int, int],
    model: LensModel,
    *,
    guess: tuple[FloatArray, FloatArray] | None = None,
) -> MonoFit:
    """Calibrate one camera from views of a planar target with one lens model.

    Parameters
    ----------
    object_points : list of (N_i, 3) float
        Target points of each view, in the target frame, z = 0.
    image_points : list of (N_i, 2) float
        Their detected pixels.
    size : (w, h)
    model : LensModel
    guess : (K, dist), optional
        Start from these intrinsics (the distortion cut or padded to the model's length).

    Raises
    ------
    DegenerateDataError
        OpenCV refuses the views (too few, or all in one plane orientation); the message
        names the likely cause.
    """
    obj = [np.asarray(o, dtype=np.float32).reshape(-1, 1, 3) for o in object_points]
    img = [np.asarray(q, dtype=np.float32).reshape(-1, 1, 2) for q in image_points]
    flags = model.flags
    K0: FloatArray | None = None
    d0: FloatArray | None = None
    if guess is not None:
        K0 = np.asarray(guess[0], dtype=np.float64).copy()
        d0 = dist_of_length(guess[1], model.n_coefficients)
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    try:
        rms, K, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
            obj, img, size, K0, d0, flags=flags, criteria=_CRITERIA
        )
    except cv2.error as exc:
        raise DegenerateDataError(
            f"the camera cannot be calibrated from these {len(obj)} views with lens model "
            f"{model.name} (OpenCV: {opencv_reason(exc)}); the views need "
            "different tilts of the target"
        ) from None
    if not np.all(np.isfinite(K)) or not np.isfinite(rms):
        raise DegenerateDataError(
            f"the camera calibration with lens model {model.name} did not converge; the views "
            "need different tilts of the target"
        )
    dist_out = dist_of_length(dist, model.n_coefficients)
    std = np.asarray(std_in, dtype=np.float64).ravel()
    return MonoFit(
        model,
        float(rms),
        np.asarray(K, dtype=np.float64),
        dist_out,
        [np.asarray(r, dtype=np.float64).ravel() for r in rvecs],
        [np.asarray(t, dtype=np.float64).ravel() for t in tvecs],
        np.asarray(per_view, dtype=np.float64).ravel(),
        np.concatenate([std[:4], std[4 : 4 + model.n_coefficients]]),
    )


def _fit_from_guess(
    object_points: Sequence[FloatArray],
    image_points: Sequence[FloatArray],
    size: tuple[int, int],
    model: LensModel,
    guess: tuple[FloatArray, FloatArray] | None,
) -> MonoFit:
    """:func:`fit_camera` started from ``guess`` (the simpler model's intrinsics), and from
    OpenCV's own start where that start is refused (OpenCV rejects a guessed principal point
    it judges outside the image, where a fit from scratch succeeds)."""
    try:
        return fit_camera(object_points, image_points, size, model, guess=guess)
    except DegenerateDataError:
        if guess is None:
            raise
    return fit_camera(object_points, image_points, size, model)


def field_of_view_deg(K: FloatArray, size: tuple[int, int]) -> float:
    """Diagonal field of view of a pinhole camera, degrees."""
    w, h = size
    half = np.hypot(w / (2.0 * K[0, 0]), h / (2.0 * K[1, 1]))
    return float(np.degrees(2.0 * np.arctan(half)))


class _Folds:
    """Interleaved cross-validation folds; each fold's fit of a model starts from its fit of
    the previous model, as the fit to all views does."""

    def __init__(
        self,
        object_points: Sequence[FloatArray],
        image_points: Sequence[FloatArray],
        size: tuple[int, int],
        folds: int,
    ) -> None:
        n = len(object_points)
        self.obj, self.img, self.size = object_points, image_points, size
        self.tests = [[i for i in range(n) if i % folds == f] for f in range(folds)]
        self.guesses: list[tuple[FloatArray, FloatArray] | None] = [None] * folds

    def held_out(self, model: LensModel) -> FloatArray | None:
        """Mean squared reprojection error of each view when held out (its pose solved with
        the intrinsics fitted to the other folds), px^2, (V,); None if a fold fails."""
        n = len(self.obj)
        out = np.zeros(n)
        for f, test in enumerate(self.tests):
            train = [i for i in range(n) if i not in test]
            try:
                fit = _fit_from_guess([self.obj[i] for i in train], [self.img[i] for i in train],
                                      self.size, model, self.guesses[f])  # fmt: skip
            except DegenerateDataError:
                return None
            self.guesses[f] = (fit.K, fit.dist)
            for i in test:
                obj = np.asarray(self.obj[i], dtype=np.float64)
                q = np.asarray(self.img[i], dtype=np.float64)
                ok, rvec, tvec = cv2.solvePnP(obj, q, fit.K, fit.dist)
                if not ok:
                    return None
                proj, _ = cv2.projectPoints(obj, rvec, tvec, fit.K, fit.dist)
                out[i] = float(np.mean(np.sum((proj.reshape(-1, 2) - q) ** 2, axis=1)))
        return out


def _typical_rms(mse: FloatArray) -> float:
    """The held-out RMS of a typical view: the square root of the views' geometric mean
    squared error (one view far outside the others' reach, badly extrapolated by every
    model, does not swamp it)."""
    return float(np.sqrt(np.exp(np.mean(np.log(np.maximum(mse, 1e-300))))))


def predicts_better(richer: FloatArray, simpler: FloatArray) -> bool:
    """The richer model predicts the held-out views better, beyond chance: the views' mean
    log-ratio of squared errors (simpler over richer) exceeds twice its standard error and
    the log of 1 + :data:`HELD_OUT_TOLERANCE`."""
    d = np.log(np.maximum(simpler, 1e-300)) - np.log(np.maximum(richer, 1e-300))
    se = float(np.std(d, ddof=1) / np.sqrt(len(d)))
    return float(np.mean(d)) > max(SIGNIFICANCE * se, float(np.log1p(HELD_OUT_TOLERANCE)))


@dataclass
class LensModelChoice:
    """The lens model chosen for a camera and the figures behind the choice.

    Attributes
    ----------
    fit : MonoFit
        The chosen model fitted to all views.
    reason : str
        One sentence: why this model.
    candidates : list of dict
        Per model tried: ``name``, ``n_free``, ``train_rms_px``, ``held_out_rms_px`` (None
        when no comparison was made).
    field_of_view_deg : float
    """

    fit: MonoFit
    reason: str
    candidates: list[dict[str, object]] = field(default_factory=list)
    field_of_view_deg: float = float("nan")


def choose_lens_model(
    object_points: Sequence[FloatArray],
    image_points: Sequence[FloatArray],
    size: tuple[int, int],
    *,
    models: Sequence[LensModel] = LENS_MODELS,
    folds: int = FOLDS,
) -> LensModelChoice:
    """Fit each lens model and keep the one that best predicts views it was not fitted to.

    Parameters
    ----------
    object_points, image_points, size
        As for :func:`fit_camera`.
    models : sequence of LensModel
        The candidates, simplest first (default all of :data:`LENS_MODELS`); one model means
        no choice.
    folds : int
        Cross-validation folds; views are dealt to them in turn.

    Returns
    -------
    LensModelChoice
    """
    first = fit_camera(object_points, image_points, size, models[0])
    fov = field_of_view_deg(first.K, size)
    if len(models) == 1:
        return LensModelChoice(first, f"lens model {models[0].name} as asked", [], fov)
    if fov < NARROW_FIELD_DEG:
        narrow = lens_model("radial1")
        fit = (
            first if models[0] == narrow else fit_camera(object_points, image_points, size, narrow)
        )
        return LensModelChoice(
            fit,
            f"narrow field ({fov:.1f} deg diagonal < {NARROW_FIELD_DEG:g}): k1 only, the higher "
            "terms trade off with the principal point",
            [_candidate(fit, None)],
            fov,
        )
    n = len(object_points)
    if n < MIN_VIEWS_TO_CHOOSE:
        simple = first
        with contextlib.suppress(DegenerateDataError):
            simple = fit_camera(object_points, image_points, size, models[1],
                                guess=(first.K, first.dist))  # fmt: skip
        return LensModelChoice(
            simple,
            f"{n} views are too few to compare lens models by held-out error (at least "
            f"{MIN_VIEWS_TO_CHOOSE}); {simple.model.name} kept",
            [_candidate(simple, None)],
            fov,
        )
    k = min(folds, n)
    cv = _Folds(object_points, image_points, size, k)
    fits: list[MonoFit] = []
    errors: list[FloatArray | None] = []
    chosen, stale = 0, 0
    for model in models:
        try:
            fit = (
                first
                if not fits
                else _fit_from_guess(
                    object_points, image_points, size, model, (fits[-1].K, fits[-1].dist)
                )
            )
        except DegenerateDataError:
            break
        e = cv.held_out(model)
        fits.append(fit)
        errors.append(e)
        best = errors[chosen]
        if e is not None and (best is None or (len(fits) > 1 and predicts_better(e, best))):
            chosen, stale = len(fits) - 1, 0
        elif len(fits) > 1:
            stale += 1
            if stale == STOP_AFTER:
                break
    held = [float("inf") if e is None else _typical_rms(e) for e in errors]
    # Never a richer model whose held-out error is worse than a simpler one's.
    chosen = next(i for i in range(chosen + 1) if held[i] <= held[chosen])
    candidates = [_candidate(f, h) for f, h in zip(fits, held, strict=True)]
    winner = fits[chosen]
    simpler = [f.model.name for f in fits[:chosen]]
    richer = [f.model.name for f in fits[chosen + 1 :]]
    why = f"held-out RMS {held[chosen]:.4f} px"
    if simpler:
        why += f", better beyond chance than {', '.join(simpler)}"
    if richer:
        why += f"; {', '.join(richer)} not better beyond chance"
    tried = "" if len(fits) == len(models) else "; the ladder stopped there"
    return LensModelChoice(
        winner, f"{winner.model.name}: {why} ({k}-fold, {n} views{tried})", candidates, fov
    )


def _candidate(fit: MonoFit, held_out_px: float | None) -> dict[str, object]:
    finite = held_out_px is not None and np.isfinite(held_out_px)
    return {
        "name": fit.model.name,
        "n_free": fit.model.n_free,
        "train_rms_px": fit.rms_px,
        "held_out_rms_px": held_out_px if finite else None,
    }
