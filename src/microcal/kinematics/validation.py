"""Validation of kinematic models (thesis 5.2.2): held-out prediction errors, Eq 5.1.

The thesis fitted on the first 110 of 170 poses and validated on the last 60. k-fold
cross-validation uses every pose once for validation, and when the fit includes a stepwise
selection, the selection is repeated inside each fold, so the figure is honest about it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import DegenerateDataError, InputError
from ..metrics.error_summary import ErrorSummary, summarize_errors
from .models import KinematicModel

__all__ = [
    "CrossValidation",
    "Validation",
    "cross_validate",
    "kfold_indices",
    "prediction_errors",
    "validate_split",
]

Fitter = Callable[[FloatArray, FloatArray], KinematicModel]


def prediction_errors(model: KinematicModel, u: ArrayLike, p_um: ArrayLike) -> FloatArray:
    """Euclidean prediction error of each sample (thesis Eq 5.1).

    Parameters
    ----------
    model : KinematicModel
    u : (N, k) float
        Inputs.
    p_um : (N, 3) float
        Measured positions, µm.

    Returns
    -------
    error_um : (N,) float
    """
    P = as_array(p_um, "p_um", (None, 3))
    out: FloatArray = np.linalg.norm(model.predict_um(u) - P, axis=1)
    return out


@dataclass(frozen=True)
class Validation:
    """Errors of a model on samples it was not fitted to."""

    model: KinematicModel
    n_fit: int
    n_validate: int
    errors_um: FloatArray  # (n_validate,) Eq 5.1
    residuals_um: FloatArray  # (n_validate, 3) measured - predicted, per axis
    summary: ErrorSummary

    def as_dict(self) -> dict[str, object]:
        """The ``validation`` object of calibration.json."""
        s = self.summary.as_dict("_um")
        del s["n"]
        rms_axis = np.sqrt(np.mean(self.residuals_um**2, axis=0))
        return {
            "n_fit": self.n_fit,
            "n_validate": self.n_validate,
            **s,
            "rms_axis_um": {axis: float(v) for axis, v in zip("xyz", rms_axis, strict=True)},
        }


def validate_split(fit: Fitter, u: ArrayLike, p_um: ArrayLike, n_fit: int) -> Validation:
    """Fit on the first ``n_fit`` samples and validate on the rest (the thesis's split).

    Parameters
    ----------
    fit : callable (u, p_um) -> KinematicModel
    u : (N, k) float
    p_um : (N, 3) float
    n_fit : int
        0 < n_fit < N.
    """
    U = as_array(u, "u", (None, None))
    P = as_array(p_um, "p_um", (U.shape[0], 3))
    n = U.shape[0]
    if not 0 < n_fit < n:
        raise InputError(f"n_fit: expected between 1 and {n - 1} for {n} samples, got {n_fit}")
    model = fit(U[:n_fit], P[:n_fit])
    residuals = P[n_fit:] - model.predict_um(U[n_fit:])
    errors = np.linalg.norm(residuals, axis=1)
    return Validation(model, n_fit, n - n_fit, errors, residuals, summarize_errors(errors))


def kfold_indices(n: int, k: int, seed: int = 0) -> list[FloatArray]:
    """Split ``range(n)`` into ``k`` folds of near-equal size, shuffled by ``seed``."""
    if not 2 <= k <= n:
        raise InputError(f"folds: expected between 2 and {n} for {n} samples, got {k}")
    order = np.random.default_rng(seed).permutation(n)
    return [np.sort(f) for f in np.array_split(order, k)]


@dataclass(frozen=True)
class CrossValidation:
    """k-fold cross-validation of a fitting procedure (selection included)."""

    k: int
    errors_um: FloatArray  # (N,) each sample's error when it was held out
    summary: ErrorSummary
    term_frequency: FloatArray  # (3, m) fraction of folds that selected each term per axis
    term_names: tuple[str, ...]

    def as_dict(self) -> dict[str, object]:
        """Plain dict for JSON."""
        s = self.summary.as_dict("_um")
        return {
            "folds": self.k,
            **s,
            "term_frequency": {
                axis: dict(zip(self.term_names, self.term_frequency[i].tolist(), strict=True))
                for i, axis in enumerate("xyz")
            },
        }


def cross_validate(
    fit: Fitter, u: ArrayLike, p_um: ArrayLike, k: int = 10, seed: int = 0
) -> CrossValidation:
    """k-fold cross-validation: every sample is predicted by a model fitted without it.

    Parameters
    ----------
    fit : callable (u, p_um) -> KinematicModel
        The whole procedure, selection included.
    u : (N, k) float
    p_um : (N, 3) float
    k : int
        Number of folds.
    seed : int
        Seed of the shuffle that forms the folds.
    """
    U = as_array(u, "u", (None, None))
    P = as_array(p_um, "p_um", (U.shape[0], 3))
    n = U.shape[0]
    errors = np.empty(n)
    freq: FloatArray | None = None
    names: tuple[str, ...] = ()
    for fold in kfold_indices(n, k, seed):
        train = np.setdiff1d(np.arange(n), fold)
        try:
            model = fit(U[train], P[train])
        except DegenerateDataError as exc:
            raise DegenerateDataError(f"cross-validation with {k} folds: {exc}") from None
        errors[fold] = prediction_errors(model, U[fold], P[fold])
        sel = model.selected.astype(float)
        freq = sel if freq is None else freq + sel
        names = tuple(t.name for t in model.terms)
    assert freq is not None
    return CrossValidation(k, errors, summarize_errors(errors), freq / k, names)
