"""The Bayes floor of the population: kriging under each draw's own prior."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.errors import InputError
from microcal.kinematics.families import FAMILIES, fit_family
from microcal.procedures.study import StudyConfig, run_seed
from microcal.sim.population import draw_population
from microcal.sim.population_prior import (
    fit_prior_estimator,
    known_form_terms,
    profile_variance_um2,
)

TRAVEL = np.array([[0.0, 8000.0], [0.0, 8000.0], [0.0, 4800.0]])
INPUTS = ("dx", "dy", "dz", "sx", "sy", "sz")


def _poses(seed: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d = rng.uniform(TRAVEL[:, 0], TRAVEL[:, 1], (n, 3))
    signs = rng.choice([-1.0, 1.0], (n, 3))
    return d, signs


def test_each_draw_records_the_prior_its_profiles_came_from():
    draw = draw_population(3)
    assert np.all((draw.profile_length_um >= 800) & (draw.profile_length_um <= 2000))
    assert np.all((draw.straightness_sd_um >= 0.5) & (draw.straightness_sd_um <= 1.5))
    assert np.all((draw.angle_sd_urad >= 10) & (draw.angle_sd_urad <= 50))
    var = profile_variance_um2(draw)
    # a joint's straightness leaves its own axis alone: only the Abbe part is there
    r2 = draw.truth.joint_errors.tool_offset_um**2
    for j in range(3):
        abbe = (1e-6 * draw.angle_sd_urad[j]) ** 2 * (r2.sum() - r2[j])
        assert var[j, j] == pytest.approx(abbe, rel=1e-12)
    # the realised profiles' spread over 20 draws matches the prior's variance (a factor
    # of 2 either way is ~6 sd of the mean of 20 ratios; the process is strongly correlated)
    ratios = []
    for seed in range(20):
        draw = draw_population(seed)
        errors = draw.truth.joint_errors
        d = np.zeros((400, 3))
        for j in range(3):
            one = d.copy()
            one[:, j] = np.linspace(0.0, 8000.0 if j < 2 else 4800.0, 400)
            prof = errors.smooth_um(one) - errors.smooth_um(d[:1])
            ratios.append(np.var(prof, axis=0).sum() / profile_variance_um2(draw)[:, j].sum())
    assert 0.5 < float(np.mean(ratios)) < 2.0


def test_without_noise_it_follows_the_profiles_no_polynomial_can():
    draw = draw_population(6)
    d, signs = _poses(0, 300)
    u = np.column_stack([d, signs])
    p = draw.truth.position_um(d, signs)
    est = fit_prior_estimator(draw, u[:250], INPUTS, p[:250], np.full((250, 3), 1e-6))
    err = np.linalg.norm(est.predict_um(u[250:]) - p[250:], axis=1)
    quad = fit_family(u[:250], p[:250], FAMILIES["quadratic"], INPUTS,
                      {"sx": 1, "sy": 1, "sz": 1}, TRAVEL)  # fmt: skip
    quad_err = np.linalg.norm(quad.predict_um(u[250:]) - p[250:], axis=1)
    assert err.mean() < 0.15  # µm: what is left is the sensors' periodic error
    assert err.mean() < 0.2 * quad_err.mean()


def test_with_noise_no_model_beats_it_on_average():
    """The Bayes estimator under the true prior: over draws, the penalised ``smooth``
    family predicts held-out poses no better (a tenth of slack for five draws)."""
    mine, smooth = [], []
    for seed in range(5):
        draw = draw_population(seed)
        d, signs = _poses(seed + 10, 230)
        u = np.column_stack([d, signs])
        truth = draw.truth.position_um(d, signs)
        p = truth + np.random.default_rng(seed).normal(0.0, 0.4, truth.shape)
        est = fit_prior_estimator(draw, u[:150], INPUTS, p[:150], np.full((150, 3), 0.16))
        fit = fit_family(u[:150], p[:150], FAMILIES["smooth"], INPUTS,
                         {"sx": 1, "sy": 1, "sz": 1}, TRAVEL)  # fmt: skip
        mine.append(np.linalg.norm(est.predict_um(u[150:]) - truth[150:], axis=1).mean())
        smooth.append(np.linalg.norm(fit.predict_um(u[150:]) - truth[150:], axis=1).mean())
    assert np.mean(mine) <= 1.1 * np.mean(smooth)


def test_known_form_terms_and_bad_inputs():
    names = [t.name for t in known_form_terms(("dx", "dy", "dz", "sx", "sy", "sz", "T"))]
    assert names[-1] == "1"
    assert len(names) == 17
    assert {"sx", "T", "sx*dx", "dx*dy", "dz^2"} <= set(names)
    draw = draw_population(0)
    u = np.zeros((5, 6))
    with pytest.raises(InputError, match="joints"):
        fit_prior_estimator(draw, u, ("sx", "sy", "sz", "dx", "dy", "dz"), u[:, :3], u[:, :3])
    with pytest.raises(InputError, match=r"expected \(5, 3\)"):
        fit_prior_estimator(draw, u, INPUTS, u[:, :3], u[:3, :3])


def test_a_study_seed_reports_the_prior_on_the_population_only():
    config = StudyConfig(poses=80, cycles=1, prior=True)
    run = run_seed("population", 2, config)
    ap = run.ap_truth_mean_um
    assert ap["oracle"] < ap["prior"] < ap["quadratic"]
    assert run.validation_mean_um["prior"] < run.validation_mean_um["quadratic"]
    with pytest.raises(InputError, match="only the population preset"):
        run_seed("thesis", 2, StudyConfig(poses=60, cycles=1, prior=True))
