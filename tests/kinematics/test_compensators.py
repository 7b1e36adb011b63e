"""Compensators (thesis 4.4): matrix (Eq 4.16) and optimal (Eq 4.17-4.19)."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from microcal import DegenerateDataError, InputError, LimitError
from microcal.kinematics import fit_matrix_model, fit_polynomial_model
from microcal.kinematics.compensators import Compensator, matrix_compensator, optimal_compensator
from microcal.sim.synthetic_run import synthetic_run
from microcal.sim.thesis_kinematics import thesis_kinematics

LOW = np.array([0.0, 0.0, 0.0])
HIGH = np.array([8000.0, 8000.0, 4800.0])


@pytest.fixture(scope="module")
def poly():
    run = synthetic_run(170, seed=8)
    return fit_polynomial_model(run.d_um, run.measured_um)


@pytest.fixture(scope="module")
def truth_model():
    return thesis_kinematics().static


def test_matrix_compensator_inverts_the_matrix_model_exactly(rng):
    run = synthetic_run(170, seed=9)
    m = fit_matrix_model(run.d_um, run.measured_um)
    p = rng.uniform(LOW, HIGH, (1000, 3)) + m.p_base_um
    d = matrix_compensator(m, p)
    # Metric: worst-case |model(d) - p|, µm.
    assert np.abs(m.predict_um(d) - p).max() < 1e-9


def test_round_trip_10000_targets_seeded(poly, rng):
    d_true = rng.uniform(LOW, HIGH, (10_000, 3))
    p = poly.predict_um(d_true)
    c = optimal_compensator(poly, p)
    # >= 99.9 % converge; converged targets are reproduced within 1e-6 µm by the model.
    assert c.converged.mean() >= 0.999
    err = np.linalg.norm(poly.predict_um(c.d_um[c.converged]) - p[c.converged], axis=1)
    assert err.max() <= 1e-6
    np.testing.assert_allclose(c.d_um, d_true, atol=1e-6)
    assert c.iterations <= 3


@given(
    d=st.tuples(st.floats(0, 8000), st.floats(0, 8000), st.floats(0, 4800)),
    seed=st.integers(0, 50),
)
def test_round_trip_property(truth_model, d, seed):
    # Any target the true kinematics can reach: the optimal compensator finds its joints.
    p = truth_model.predict_um(np.array(d))
    c = optimal_compensator(truth_model, p)
    assert c.converged.all()
    assert np.abs(truth_model.predict_um(c.d_um) - p).max() <= 1e-6
    assert np.abs(c.d_um[0] - np.array(d)).max() <= 1e-6


def test_temperature_is_given_not_solved(rng):
    truth = thesis_kinematics()
    d = rng.uniform(LOW, HIGH, (300, 3))
    T = rng.uniform(20.0, 25.0, 300)
    m = fit_polynomial_model(np.column_stack([d, T]), truth.position_um(d, temperature_c=T),
                             select="all", extra={"T": 2})  # fmt: skip
    targets = truth.position_um(d[:50], temperature_c=23.5)
    c = optimal_compensator(m, targets, extra=23.5)
    assert c.converged.all()
    np.testing.assert_allclose(c.d_um, d[:50], atol=1e-6)
    with pytest.raises(InputError, match=r"this model also needs T \(ambient temperature"):
        optimal_compensator(m, targets)


def test_limits_refuse_instead_of_clipping(poly):
    p = poly.predict_um(np.array([[1000.0, 1000.0, 4700.0]]))
    limits = np.array([[0, 8000], [0, 8000], [0, 4500.0]])
    with pytest.raises(
        LimitError,
        match=r"target 1: axis z = 4700.000 µm for target .* is outside the soft limits "
        r"\[0, 4500\] µm; nothing was moved",
    ):
        optimal_compensator(poly, p, limits_um=limits)
    with pytest.raises(LimitError, match=r"target 1: axis z = .* soft limits \[0, 4500\]"):
        matrix_compensator(poly, p, limits_um=limits)


def test_ill_conditioned_model_is_refused(poly):
    from microcal import KinematicModel

    data = poly.to_dict()
    coef = np.array(data["coefficients"])
    coef[:, 2] = coef[:, 1]  # dz acts exactly like dy: R is singular
    selected = np.array(data["selected"], dtype=bool)
    selected[:, 2] = selected[:, 1]
    data["coefficients"] = coef.tolist()
    data["selected"] = selected.tolist()
    bad = KinematicModel.from_dict(data)
    with pytest.raises(DegenerateDataError, match="R is singular or ill-conditioned"):
        Compensator(bad)


def test_unreachable_target_is_reported_not_converged(truth_model):
    # z bends by -1.5e-6 dz²: along z the model's output peaks near dz = 333 000 µm, so a
    # target far beyond that peak has no solution.
    p = truth_model.predict_um(np.array([0.0, 0.0, 0.0])) + np.array([0.0, 0.0, 1e6])
    c = optimal_compensator(truth_model, p)
    assert not c.converged[0]
    assert c.residual_um[0] > 1.0


@pytest.mark.parametrize(
    ("target", "match"),
    [
        (np.array([[1.0, np.nan, 2.0]]), "p_um: expected finite values"),
        (np.zeros((2, 2)), r"p_um: expected shape \(N, 3\), got \(2, 2\)"),
    ],
)
def test_bad_targets(poly, target, match):
    with pytest.raises(InputError, match=match):
        optimal_compensator(poly, target)
