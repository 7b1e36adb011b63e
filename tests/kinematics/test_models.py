"""Kinematic models (Eq 4.5-4.10): fitting, Jacobian, serialisation, degenerate data."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import DegenerateDataError, FormatError, InputError, KinematicModel
from microcal.kinematics import fit_matrix_model, fit_polynomial_model
from microcal.sim.thesis_kinematics import thesis_kinematics


@pytest.fixture
def joints(rng):
    return rng.uniform([0, 0, 0], [8000, 8000, 4800], size=(170, 3))


def test_matrix_model_recovers_an_affine_map(joints, rng):
    R = np.eye(3) + rng.normal(0, 3e-3, (3, 3))
    pb = np.array([1000.0, 800.0, 300.0])
    m = fit_matrix_model(joints, joints @ R.T + pb)
    np.testing.assert_allclose(m.R, R, rtol=0, atol=1e-12)
    np.testing.assert_allclose(m.p_base_um, pb, rtol=1e-10)
    assert m.kind == "matrix"
    assert m.n_parameters == 12


def test_polynomial_model_recovers_the_true_kinematics(joints):
    truth = thesis_kinematics().static
    m = fit_polynomial_model(joints, truth.predict_um(joints), select="all")
    # Metric: worst-case position difference over the travel, µm.
    grid = np.stack(np.meshgrid(*[np.linspace(0, 8000, 5)] * 2, np.linspace(0, 4800, 5)), -1)
    grid = grid.reshape(-1, 3)
    assert np.abs(m.predict_um(grid) - truth.predict_um(grid)).max() < 1e-8


def test_stepwise_with_noise_finds_the_strong_terms(joints, rng):
    truth = thesis_kinematics().static
    p = truth.predict_um(joints) + rng.normal(0, 0.5, joints.shape)
    m = fit_polynomial_model(joints, p)
    names = [t.name for t in m.terms]
    assert m.selected[2, names.index("dz^2")]  # the bending of z
    assert m.selected[1, names.index("dz")]  # the y-z coupling
    assert m.selection["method"] == "stepwise"
    assert len(m.selection["history"]) == 3


def test_jacobian_matches_finite_differences(joints, rng):
    m = fit_polynomial_model(joints, thesis_kinematics().static.predict_um(joints), select="all")
    u = joints[:20]
    J = m.jacobian(u)
    h = 1e-2
    for b in range(3):
        du = np.zeros(3)
        du[b] = h
        fd = (m.predict_um(u + du) - m.predict_um(u - du)) / (2 * h)
        # Metric: worst-case absolute difference, µm/µm (the model is quadratic: central
        # differences are exact up to rounding).
        assert np.abs(J[:, :, b] - fd).max() < 1e-8


def test_temperature_terms(joints, rng):
    T = rng.uniform(20, 25, joints.shape[0])
    truth = thesis_kinematics()
    p = truth.position_um(joints, temperature_c=T)
    m = fit_polynomial_model(np.column_stack([joints, T]), p, select="all", extra={"T": 2})
    assert m.inputs == ("dx", "dy", "dz", "T")
    assert m.joints == ("dx", "dy", "dz")
    names = [t.name for t in m.terms]
    np.testing.assert_allclose(
        m.coefficients[:, names.index("T")], truth.thermal_um_per_c, atol=1e-6
    )
    assert m.jacobian(np.column_stack([joints, T])[:3]).shape == (3, 3, 3)


def test_serialisation_round_trip(joints, rng):
    p = thesis_kinematics().static.predict_um(joints) + rng.normal(0, 1, joints.shape)
    m = fit_polynomial_model(joints, p)
    back = KinematicModel.from_dict(m.to_dict())
    np.testing.assert_array_equal(back.coefficients, m.coefficients)
    np.testing.assert_array_equal(back.selected, m.selected)
    np.testing.assert_array_equal(back.covariance, m.covariance)
    assert [t.name for t in back.terms] == [t.name for t in m.terms]
    np.testing.assert_array_equal(back.predict_um(joints), m.predict_um(joints))


def test_prediction_std_is_positive_and_grows_outside(joints, rng):
    p = thesis_kinematics().static.predict_um(joints) + rng.normal(0, 1, joints.shape)
    m = fit_matrix_model(joints, p)
    inside = m.prediction_std_um([4000, 4000, 2400])
    outside = m.prediction_std_um([40000, 40000, 24000])
    assert np.all(inside > 0)
    assert np.all(outside > 5 * inside)


def test_the_prediction_covariance_matches_the_scatter_of_refitted_models():
    """Monte Carlo: one design fitted 300 times with fresh noise (0.5 µm); the scatter of the
    predictions at four poses (their variances and the correlations between the poses)
    against the covariance propagated from the coefficients (averaged over the fits, as each
    fit's own noise estimate scatters)."""
    rng = np.random.default_rng(21)
    d = rng.uniform([0, 0, 0], [8000, 8000, 4800], (30, 3))
    truth = thesis_kinematics().static
    at = np.array([[4000, 4000, 2400], [800, 800, 480], [7200, 800, 4320], [7200, 7200, 480]])
    preds, covs = [], []
    for _ in range(300):
        p = truth.predict_um(d) + rng.normal(0, 0.5, d.shape)
        m = fit_polynomial_model(d, p, select="all")
        preds.append(m.predict_um(at))
        covs.append(m.prediction_covariance_um2(at))
    assert covs[0].shape == (3, 4, 4)
    np.testing.assert_allclose(np.diagonal(covs[-1], axis1=1, axis2=2).T,
                               m.prediction_std_um(at) ** 2, rtol=1e-10)  # fmt: skip
    cov, scatter = np.mean(covs, axis=0), np.array(preds)
    for axis in range(3):
        seen = np.cov(scatter[:, :, axis].T)
        # variances within 25 % (300 fits: 8 % standard error)
        np.testing.assert_allclose(np.diag(cov[axis]), np.diag(seen), rtol=0.25)
        # correlations between the poses within 0.15 (300 fits: 0.06 or less)
        corr = cov[axis] / np.sqrt(np.outer(np.diag(cov[axis]), np.diag(cov[axis])))
        seen_corr = seen / np.sqrt(np.outer(np.diag(seen), np.diag(seen)))
        np.testing.assert_allclose(corr, seen_corr, atol=0.15)


@pytest.mark.parametrize(
    ("make", "error", "match"),
    [
        (
            "few",
            DegenerateDataError,
            "expected more samples than candidate terms, got 8 samples for 10",
        ),
        ("still", DegenerateDataError, "input 'dy' has the same value in every sample"),
        ("nan", DegenerateDataError, r"p_um: 1 sample\(s\) with NaN or infinite values \(rows 5\)"),
        ("shape", InputError, r"p_um: expected shape \(170, 3\), got \(170, 2\)"),
        ("plane", DegenerateDataError, "is a linear combination of the others"),
    ],
)
def test_degenerate_data_is_refused(joints, make, error, match):
    d = joints.copy()
    p = thesis_kinematics().static.predict_um(d)
    if make == "few":
        d, p = d[:8], p[:8]
    if make == "still":
        d[:, 1] = 1234.0
    if make == "nan":
        p[5, 2] = np.nan
    if make == "shape":
        p = p[:, :2]
    if make == "plane":
        d[:, 2] = 0.5 * d[:, 0] + 0.1 * d[:, 1]  # z never moves independently
    with pytest.raises(error, match=match):
        fit_polynomial_model(d, p, select="all")


def test_from_dict_names_the_problem(joints):
    data = fit_matrix_model(joints, joints).to_dict()
    bad = dict(data, coefficients=[[1.0, 2.0]] * 3)
    with pytest.raises(FormatError, match=r"expected coefficients \(3, 4\)"):
        KinematicModel.from_dict(bad)
    with pytest.raises(FormatError, match="missing key 'terms'"):
        KinematicModel.from_dict({k: v for k, v in data.items() if k != "terms"})
    with pytest.raises(FormatError, match="term 'dx\\^x'"):
        KinematicModel.from_dict(dict(data, terms=["dx^x", "dy", "dz", "1"]))
