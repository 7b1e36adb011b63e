"""Ordinary least squares with the statistics a metrologist asks for (thesis Eq 4.14).

The columns are scaled to unit RMS before a column-pivoted QR factorisation; the normal
equations are never formed and no explicit inverse of them is taken. Standard errors and
the covariance come from the triangular factor: ``cov = s^2 R^-1 R^-T``.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import scipy.linalg
import scipy.stats
from numpy.typing import ArrayLike

from .._validation import FloatArray, as_array
from ..errors import DegenerateDataError, InputError

__all__ = ["RANK_RTOL", "LinearFit", "fit_least_squares"]

#: A column whose part independent of the others is below this fraction of the largest
#: (after scaling to unit RMS) makes the design rank-deficient.
RANK_RTOL = 1e-10


@dataclass(frozen=True)
class LinearFit:
    """Result of :func:`fit_least_squares` for ``y ~ X b``.

    Attributes
    ----------
    coef : (m,) float
    se : (m,) float
        Standard errors of the coefficients.
    covariance : (m, m) float
        Covariance of the coefficients (``s^2 (X^T X)^-1``).
    residuals : (N,) float
        ``y - X coef``.
    rmse : float
        Residual standard deviation ``s = sqrt(RSS / dof)``.
    dof : int
        Residual degrees of freedom ``N - m``.
    condition_number : float
        Of the design after scaling its columns to unit RMS.
    """

    coef: FloatArray
    se: FloatArray
    covariance: FloatArray
    residuals: FloatArray
    rmse: float
    dof: int
    condition_number: float

    @property
    def tstat(self) -> FloatArray:
        """t statistics of the coefficients."""
        with np.errstate(divide="ignore", invalid="ignore"):
            out: FloatArray = self.coef / self.se
        return out

    @property
    def pval(self) -> FloatArray:
        """Two-sided p-values of the t tests ``coef = 0``."""
        out: FloatArray = 2.0 * scipy.stats.t.sf(np.abs(self.tstat), self.dof)
        return out


def check_design(X: FloatArray, names: Sequence[str]) -> None:
    """Raise DegenerateDataError naming the column that makes X rank-deficient."""
    _n, m = X.shape
    scale = np.sqrt(np.mean(X**2, axis=0))
    for j in np.flatnonzero(scale == 0).tolist():
        raise DegenerateDataError(
            f"column {names[j]!r} is zero for every sample: the design cannot determine its "
            f"coefficient (was that axis never moved?)"
        )
    _, R, piv = scipy.linalg.qr(X / scale, mode="economic", pivoting=True)
    diag = np.abs(np.diag(R))
    if m and diag[-1] <= RANK_RTOL * diag[0]:
        bad = names[int(piv[-1])]
        raise DegenerateDataError(
            f"column {bad!r} is a linear combination of the others: the design is rank "
            f"deficient (move the axes independently, over more of their range)"
        )


def fit_least_squares(X: ArrayLike, y: ArrayLike, names: Sequence[str] | None = None) -> LinearFit:
    """Fit ``y ~ X b`` by least squares, with standard errors and covariance.

    Parameters
    ----------
    X : (N, m) float
        Design matrix; include a column of ones for an intercept.
    y : (N,) float
    names : sequence of m str, optional
        Column names for error messages.

    Raises
    ------
    DegenerateDataError
        Fewer samples than m + 1 (no residual degrees of freedom), a zero column, or
        columns that are linearly dependent.
    InputError
        Wrong shapes or non-finite values.
    """
    X = as_array(X, "X", (None, None))
    n, m = X.shape
    y = as_array(y, "y", (n,))
    col_names = list(names) if names is not None else [f"column {j}" for j in range(m)]
    if len(col_names) != m:
        raise InputError(f"names: expected {m} names, got {len(col_names)}")
    if n <= m:
        raise DegenerateDataError(
            f"fit: expected more samples than coefficients, got {n} samples for {m} "
            f"coefficients; acquire more poses"
        )
    check_design(X, col_names)
    scale = np.sqrt(np.mean(X**2, axis=0))
    Xs = X / scale
    Q, R = scipy.linalg.qr(Xs, mode="economic")
    coef_s = scipy.linalg.solve_triangular(R, Q.T @ y)
    residuals = y - Xs @ coef_s
    dof = n - m
    rss = float(residuals @ residuals)
    s2 = rss / dof
    Rinv = scipy.linalg.solve_triangular(R, np.eye(m))
    cov_s = s2 * (Rinv @ Rinv.T)
    coef = coef_s / scale
    cov = cov_s / np.outer(scale, scale)
    sv = np.linalg.svd(Xs, compute_uv=False)
    return LinearFit(
        coef=np.asarray(coef, dtype=np.float64),
        se=np.sqrt(np.diag(cov)),
        covariance=np.asarray(cov, dtype=np.float64),
        residuals=np.asarray(residuals, dtype=np.float64),
        rmse=float(np.sqrt(s2)),
        dof=dof,
        condition_number=float(sv[0] / sv[-1]),
    )
