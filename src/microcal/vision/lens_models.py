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
refitted), over interleaved folds; it keeps the simplest model whose held-out RMS is within
:data:`HELD_OUT_TOLERANCE` of the best. A richer model is therefore never chosen when a
simpler one predicts the held-out views as well or better.

Narrow-field (microscope) cameras keep the one constraint that makes them well posed: below
:data:`NARROW_FIELD_DEG` of diagonal field, the terms beyond k1 trade off with the principal
point and the focal length, and only ``radial1`` is offered.
"""

from __future__ import annotations

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
    "field_of_view_deg",
    "fit_camera",
    "lens_model",
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

#: A model is as good as the best when its held-out RMS is within this fraction of it.
HELD_OUT_TOLERANCE = 0.02
#: Below this diagonal field of view (degrees) a camera is narrow-field: k1 only.
NARROW_FIELD_DEG = 10.0
#: Folds of the cross-validation (fewer when there are fewer views).
FOLDS = 5
#: Views needed to compare models by held-out error.
MIN_VIEWS_TO_CHOOSE = 4

_CRITERIA = (cv2.TERM_CRITERIA_COUNT + cv2.TERM_CRITERIA_EPS, 100, 1e-9)


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
        d0 = np.zeros(model.n_coefficients)
        given = np.asarray(guess[1], dtype=np.float64).ravel()[: model.n_coefficients]
        d0[: given.size] = given
        flags |= cv2.CALIB_USE_INTRINSIC_GUESS
    try:
        rms, K, dist, rvecs, tvecs, std_in, _, per_view = cv2.calibrateCameraExtended(
            obj, img, size, K0, d0, flags=flags, criteria=_CRITERIA
        )
    except cv2.error as exc:
        raise DegenerateDataError(
            f"the camera cannot be calibrated from these {len(obj)} views with lens model "
            f"{model.name} (OpenCV: {str(exc).strip().splitlines()[-1]}); the views need "
            "different tilts of the target"
        ) from None
    if not np.all(np.isfinite(K)) or not np.isfinite(rms):
        raise DegenerateDataError(
            f"the camera calibration with lens model {model.name} did not converge; the views "
            "need different tilts of the target"
        )
    dist_out = np.zeros(model.n_coefficients)
    flat = np.asarray(dist, dtype=np.float64).ravel()[: model.n_coefficients]
    dist_out[: flat.size] = flat
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


def field_of_view_deg(K: FloatArray, size: tuple[int, int]) -> float:
    """Diagonal field of view of a pinhole camera, degrees."""
    w, h = size
    half = np.hypot(w / (2.0 * K[0, 0]), h / (2.0 * K[1, 1]))
    return float(np.degrees(2.0 * np.arctan(half)))


def _held_out_rms(
    object_points: Sequence[FloatArray],
    image_points: Sequence[FloatArray],
    size: tuple[int, int],
    models: Sequence[LensModel],
    folds: int,
) -> list[float]:
    """Held-out RMS of each model; each fold's fit starts from its fit of the previous model."""
    n = len(object_points)
    sq = np.zeros(len(models))
    count = 0
    for fold in range(folds):
        test = [i for i in range(n) if i % folds == fold]
        train = [i for i in range(n) if i % folds != fold]
        guess: tuple[FloatArray, FloatArray] | None = None
        for m, model in enumerate(models):
            try:
                train_obj = [object_points[i] for i in train]
                train_img = [image_points[i] for i in train]
                fit = fit_camera(train_obj, train_img, size, model, guess=guess)
            except DegenerateDataError:
                sq[m] = np.inf
                continue
            guess = (fit.K, fit.dist)
            for i in test:
                obj = np.asarray(object_points[i], dtype=np.float64)
                q = np.asarray(image_points[i], dtype=np.float64)
                ok, rvec, tvec = cv2.solvePnP(obj, q, fit.K, fit.dist)
                if not ok:
                    sq[m] = np.inf
                    continue
                proj, _ = cv2.projectPoints(obj, rvec, tvec, fit.K, fit.dist)
                sq[m] += float(np.sum((proj.reshape(-1, 2) - q) ** 2))
        count += sum(len(image_points[i]) for i in test)
    return [float(v) for v in np.sqrt(sq / max(count, 1))]


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
            [
                {
                    "name": narrow.name,
                    "n_free": 1,
                    "train_rms_px": fit.rms_px,
                    "held_out_rms_px": None,
                }
            ],
            fov,
        )
    n = len(object_points)
    fits: list[MonoFit] = [first]
    for model in models[1:]:
        try:
            prev = fits[-1]
            fits.append(fit_camera(object_points, image_points, size, model,
                                   guess=(prev.K, prev.dist)))  # fmt: skip
        except DegenerateDataError:
            break
    if n < MIN_VIEWS_TO_CHOOSE:
        simple = fits[min(1, len(fits) - 1)]
        return LensModelChoice(
            simple,
            f"{n} views are too few to compare lens models by held-out error (at least "
            f"{MIN_VIEWS_TO_CHOOSE}); {simple.model.name} kept",
            [
                {
                    "name": f.model.name,
                    "n_free": f.model.n_free,
                    "train_rms_px": f.rms_px,
                    "held_out_rms_px": None,
                }
                for f in fits
            ],
            fov,
        )
    k = min(folds, n)
    held = _held_out_rms(object_points, image_points, size, [f.model for f in fits], k)
    best = min(held)
    chosen = next(i for i, h in enumerate(held) if h <= best * (1.0 + HELD_OUT_TOLERANCE))
    candidates: list[dict[str, object]] = [
        {
            "name": f.model.name,
            "n_free": f.model.n_free,
            "train_rms_px": f.rms_px,
            "held_out_rms_px": h if np.isfinite(h) else None,
        }
        for f, h in zip(fits, held, strict=True)
    ]
    winner = fits[chosen]
    if chosen == int(np.argmin(held)):
        why = f"the lowest held-out RMS, {held[chosen]:.4f} px"
    else:
        richest = fits[int(np.argmin(held))].model.name
        why = (
            f"held-out RMS {held[chosen]:.4f} px, within {HELD_OUT_TOLERANCE:.0%} of the best "
            f"({richest}, {best:.4f} px) with fewer terms"
        )
    return LensModelChoice(
        winner, f"{winner.model.name}: {why} ({k}-fold, {n} views)", candidates, fov
    )
