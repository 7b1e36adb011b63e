"""Penalised least squares: smooth terms whose roughness costs, the smoothing chosen by GCV.

Stepwise selection among many smooth candidate terms (waves along each joint) keeps a term
or drops it whole, and picks up noise: its predictions scatter most where poses are few,
at the ends of the travel. A penalised fit keeps every candidate and shrinks the rough
ones instead (a penalised regression spline in another basis):

    minimise  |y - X b|^2 + lambda * sum_a w_a b_a^2

with ``w_a`` zero for the unpenalised terms (the polynomial, the extra inputs) and, for
the wave ``cos k[...]``, ``k^4``: the integrated squared second derivative of that basis
function, up to a constant, so the penalty is the profile's curvature. ``lambda`` is chosen
per axis by generalised cross-validation (GCV, Craven and Wahba 1979) over a log grid.

The coefficients' covariance is the Bayesian one of a smoothing spline,
``sigma^2 (X^T X + lambda W)^-1`` with ``sigma^2 = RSS / (N - edf)`` (Wahba 1983): it
holds the shrinkage's bias as well as the noise, which is what gives its intervals their
coverage averaged over the travel (Nychka 1988).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from .._validation import FloatArray
from ..errors import DegenerateDataError

__all__ = ["PenalisedFit", "fit_penalised_axis", "roughness_weights"]

#: log10 of the smoothing parameters tried (on column-scaled terms).
LOG_LAMBDA_GRID = np.linspace(-4.0, 6.0, 41)


@dataclass(frozen=True)
class PenalisedFit:
    """One axis's penalised fit.

    Attributes
    ----------
    coef : (m,) float
    covariance : (m, m) float
        Bayesian covariance of the coefficients.
    lam : float
        The smoothing parameter chosen (on column-scaled terms).
    edf : float
        Effective degrees of freedom (trace of the hat matrix).
    sigma : float
        Residual standard deviation, ``sqrt(RSS / (N - edf))``.
    """

    coef: FloatArray
    covariance: FloatArray
    lam: float
    edf: float
    sigma: float


def roughness_weights(harmonics: Sequence[int]) -> FloatArray:
    """Penalty weights: 0 for a term without a wave (harmonic 0), ``k^4`` for harmonic k."""
    k = np.asarray(harmonics, dtype=np.float64)
    out: FloatArray = np.where(k > 0, k**4, 0.0)
    return out


def _gcv(
    XtX: FloatArray, Xty: FloatArray, Xs: FloatArray, y: FloatArray, penalty: FloatArray
) -> tuple[float, FloatArray, FloatArray, float] | None:
    """(GCV score, coefficients, (X^T X + P)^-1, edf) for the diagonal penalty ``penalty``."""
    n = Xs.shape[0]
    try:
        A_inv = np.linalg.inv(XtX + np.diag(penalty))
    except np.linalg.LinAlgError:
        return None
    b = A_inv @ Xty
    rss = float(np.sum((y - Xs @ b) ** 2))
    edf = float(np.sum(A_inv * XtX))  # trace(A_inv @ XtX), both symmetric
    if edf >= n - 1:
        return None
    return n * rss / (n - edf) ** 2, b, np.asarray(A_inv, dtype=np.float64), edf


def fit_penalised_axis(X: FloatArray, y: FloatArray, weights: FloatArray) -> PenalisedFit:
    """Penalised least squares of one axis, one smoothing parameter chosen by GCV.

    (One parameter for all the waves: a parameter per joint, by coordinate descent on GCV,
    fitted the simulator's population no better and covered its errors less often.)

    Parameters
    ----------
    X : (N, m) float
        Design matrix (the constant among its columns).
    y : (N,) float
    weights : (m,) float
        Penalty weight of each column (0: not penalised).

    Raises
    ------
    DegenerateDataError
        When the unpenalised columns alone are rank deficient or N is too small.
    """
    n = X.shape[0]
    scale = np.linalg.norm(X, axis=0)
    scale[scale == 0] = 1.0
    Xs = X / scale
    free = weights == 0
    if np.linalg.matrix_rank(Xs[:, free]) < int(free.sum()) or n <= int(free.sum()) + 1:
        raise DegenerateDataError(
            f"penalised fit: the unpenalised terms cannot be identified from {n} poses"
        )
    W = weights / scale**2  # the penalty on the scaled coefficients
    if np.any(~free):
        W = W / float(W[~free].max())
    XtX, Xty = Xs.T @ Xs, Xs.T @ y
    best = None
    for log_lam in LOG_LAMBDA_GRID:
        got = _gcv(XtX, Xty, Xs, y, 10.0**log_lam * W)
        if got is not None and (best is None or got[0] < best[0]):
            best = (*got, 10.0**log_lam)
    if best is None:
        raise DegenerateDataError(
            f"penalised fit: no smoothing leaves residual freedom ({n} poses)"
        )
    _, b, A_inv, edf, lam = best
    rss = float(np.sum((y - Xs @ b) ** 2))
    sigma2 = rss / (n - edf)
    cov = sigma2 * A_inv / np.outer(scale, scale)
    return PenalisedFit(b / scale, cov, float(lam), edf, float(np.sqrt(sigma2)))
