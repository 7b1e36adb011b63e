"""Least squares with statistics (Eq 4.14), checked against statsmodels' OLS."""

from __future__ import annotations

import numpy as np
import pytest
import statsmodels.api as sm

from microcal import DegenerateDataError
from microcal.kinematics import JOINTS, design_matrix, fit_least_squares, polynomial_terms


def thesis_design(rng, n=170):
    d = rng.uniform([0, 0, 0], [8000, 8000, 4800], size=(n, 3))
    return design_matrix(d, JOINTS, polynomial_terms())


def test_agrees_with_statsmodels_on_badly_scaled_columns(rng):
    # Columns range from 1 to 6.4e7 (dx² in µm²): the internal scaling keeps this exact.
    X = thesis_design(rng)
    beta = rng.normal(size=X.shape[1]) / np.sqrt(np.mean(X**2, axis=0))
    y = X @ beta + rng.normal(0, 2.0, X.shape[0])
    ours = fit_least_squares(X, y)
    ref = sm.OLS(y, X).fit()
    # Metric: relative difference per quantity.
    np.testing.assert_allclose(ours.coef, ref.params, rtol=1e-8, atol=1e-12)
    np.testing.assert_allclose(ours.se, ref.bse, rtol=1e-8)
    np.testing.assert_allclose(ours.covariance, ref.cov_params(), rtol=1e-7, atol=1e-30)
    np.testing.assert_allclose(ours.pval, ref.pvalues, rtol=1e-6, atol=1e-300)
    assert ours.rmse == pytest.approx(np.sqrt(ref.scale), rel=1e-10)
    assert ours.dof == ref.df_resid
    np.testing.assert_allclose(ours.residuals, ref.resid, atol=1e-9)
    assert 1 < ours.condition_number < 1e4


def test_exact_data_is_recovered(rng):
    X = thesis_design(rng, 50)
    beta = np.array([1.0, 2e-3, -3e-3, 1e-7, -2e-7, 3e-7, 1e-8, -1e-8, 2e-8, 1000.0])
    fit = fit_least_squares(X, X @ beta)
    np.testing.assert_allclose(fit.coef, beta, rtol=1e-8, atol=1e-15)


@pytest.mark.parametrize(
    ("make", "match"),
    [
        ("few", "expected more samples than coefficients, got 10 samples for 10"),
        ("zero", "column 'dz' is zero for every sample"),
        ("dependent", "column '.*' is a linear combination of the others"),
        ("nan", "y: expected finite values"),
    ],
)
def test_degenerate_designs_are_named(rng, make, match):
    X = thesis_design(rng, 10 if make == "few" else 40)
    names = [t.name for t in polynomial_terms()]
    y = rng.normal(size=X.shape[0])
    if make == "zero":
        X[:, 2] = 0.0
    if make == "dependent":
        X[:, 6] = 3.0 * X[:, 0] - X[:, 1]
    if make == "nan":
        y[4] = np.nan
    with pytest.raises((DegenerateDataError, ValueError), match=match):
        fit_least_squares(X, y, names)
