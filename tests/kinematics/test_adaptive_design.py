"""The adaptive design's choice and its predicted error (kinematics.adaptive_design)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.stats

from microcal.errors import InputError
from microcal.kinematics.adaptive_design import (
    AdaptiveSettings,
    candidate_joints_um,
    choose_batch,
    fit_adaptive_model,
    joint_inputs,
    predicted_tip_error_um,
    predicted_workspace_error_um,
    residual_variance_um2,
    workspace_grid_um,
)
from microcal.sim.thesis_kinematics import thesis_kinematics

LOW, HIGH = np.zeros(3), np.array([8000.0, 8000.0, 4800.0])
INPUTS = ("dx", "dy", "dz", "sx", "sy", "sz")


def _fit(d: np.ndarray, seed: int = 0) -> tuple:
    rng = np.random.default_rng(seed)
    signs = rng.choice([-1.0, 1.0], d.shape)
    p = thesis_kinematics().position_um(d, signs) + rng.normal(0.0, 0.3, d.shape)
    u = joint_inputs(d, signs, 22.0, INPUTS)
    return fit_adaptive_model(u, INPUTS, p, LOW, HIGH), u, p


def test_settings_refuse_a_missing_tolerance_and_too_few_poses() -> None:
    with pytest.raises(InputError, match="until-um"):
        AdaptiveSettings(until_um=0.0)
    with pytest.raises(InputError, match="max-poses"):
        AdaptiveSettings(until_um=1.0, max_poses=10)


def test_the_radius_of_an_isotropic_error_is_the_chi_square_quantile() -> None:
    d = np.random.default_rng(1).uniform(LOW, HIGH, (80, 3))
    model, _, _ = _fit(d)
    u = joint_inputs(np.full((1, 3), 4000.0), np.ones((1, 3)), 22.0, INPUTS)
    sd = model.prediction_std_um(u)[0]
    big = 100.0  # a scatter that dwarfs the model's own: the error is isotropic
    r = predicted_tip_error_um(model, u, big**2)[0]
    expected = np.sqrt(scipy.stats.chi2.ppf(0.95, 3) * (big**2 + np.mean(sd**2)))
    assert r == pytest.approx(expected, rel=0.03)
    assert predicted_workspace_error_um(model, np.repeat(u, 5, axis=0), big**2) == pytest.approx(
        r, rel=1e-9
    )


def test_the_choice_goes_where_the_model_has_not_been() -> None:
    settings = AdaptiveSettings(until_um=1.0, candidates=512, grid_per_axis=5)
    rng = np.random.default_rng(2)
    d = rng.uniform(LOW, HIGH * np.array([0.5, 1.0, 1.0]), (60, 3))  # x in its lower half only
    model, u, p = _fit(d)
    cand = candidate_joints_um(settings, LOW, HIGH)
    test = joint_inputs(workspace_grid_um(settings, LOW, HIGH), np.ones((125, 3)), 22.0, INPUTS)
    picks = choose_batch(model, residual_variance_um2(model, u, p), test,
                         lambda i: joint_inputs(cand, np.ones_like(cand), 22.0, INPUTS), 8,
                         d[-1], np.ones(len(cand), dtype=bool))  # fmt: skip
    assert len(set(picks)) == 8
    assert np.mean(cand[picks, 0] > 4000.0) >= 0.75  # most of them in the unseen half
    again = choose_batch(model, residual_variance_um2(model, u, p), test,
                         lambda i: joint_inputs(cand, np.ones_like(cand), 22.0, INPUTS), 8,
                         d[-1], np.ones(len(cand), dtype=bool))  # fmt: skip
    assert again == picks  # a deterministic function of what was measured


def test_a_joint_scored_with_both_directions_is_chosen_once() -> None:
    settings = AdaptiveSettings(until_um=1.0, candidates=256, grid_per_axis=5)
    d = np.random.default_rng(3).uniform(LOW, HIGH, (60, 3))
    model, u, p = _fit(d)
    cand = candidate_joints_um(settings, LOW, HIGH)
    test = joint_inputs(workspace_grid_um(settings, LOW, HIGH), np.ones((125, 3)), 22.0, INPUTS)
    both = [np.ones(3), -np.ones(3)]

    def rows(i: int) -> np.ndarray:
        return np.vstack([joint_inputs(cand, np.broadcast_to(w, cand.shape), 22.0, INPUTS)
                          for w in both])  # fmt: skip

    group = np.tile(np.arange(len(cand)), 2)
    picks = choose_batch(model, residual_variance_um2(model, u, p), test, rows, 10, d[-1],
                         np.ones(2 * len(cand), dtype=bool), 1.0, 2, group)  # fmt: skip
    joints = [k % len(cand) for k in picks]
    assert len(set(joints)) == 10  # never one joint twice, whatever its directions


def test_the_start_under_the_prior_is_spread_to_the_faces_and_fixed() -> None:
    from microcal.procedures.acquisition import AcquisitionConfig
    from microcal.procedures.adaptive import AdaptiveDesign

    settings = AdaptiveSettings(
        until_um=1.0, candidates=256, grid_per_axis=5, start="prior", exchange=0
    )
    limits = np.column_stack([LOW - 500.0, HIGH + 500.0])
    approach = AcquisitionConfig(approach_um=300.0, approach_seed=1)
    start = AdaptiveDesign(settings, LOW, HIGH, limits, approach).start_um()
    assert start.shape == (20, 3)
    assert len(np.unique(start, axis=0)) == 20
    span = (start - LOW) / (HIGH - LOW)
    assert np.all(span.min(axis=0) <= 0.05)
    assert np.all(span.max(axis=0) >= 0.95)
    again = AdaptiveDesign(settings, LOW, HIGH, limits, approach).start_um()
    np.testing.assert_array_equal(again, start)  # a function of the settings alone
