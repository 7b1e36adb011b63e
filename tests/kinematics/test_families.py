"""Wave terms, model families and their choice by held-out error."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import InputError
from microcal.kinematics import KinematicModel, parse_term
from microcal.kinematics.compensators import Compensator
from microcal.kinematics.families import FAMILIES, choose_family, fit_family
from microcal.kinematics.terms import JOINTS, design_matrix, design_matrix_derivative

RANGE_UM = np.array([[0.0, 8000.0], [0.0, 8000.0], [0.0, 4800.0]])


def _data(seed: int, wavy: bool, n: int = 170) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    d = rng.uniform(0.0, RANGE_UM[:, 1], (n, 3))
    p = d @ np.array([[1.0005, 0.002, 0.0], [-0.001, 0.9995, 0.003], [0.0, 0.001, 1.0002]]).T
    p = p + np.array([1000.0, 800.0, 300.0]) + 2e-7 * d[:, [2, 0, 1]] ** 2
    if wavy:  # a straightness profile no quadratic follows
        p[:, 1] += 1.5 * np.sin(d[:, 0] / 900.0)
        p[:, 2] += 1.0 * np.cos(d[:, 1] / 1100.0)
    return d, p + rng.normal(0.0, 0.3, (n, 3))


@pytest.mark.parametrize(
    "name", ["cos3[dx:0:8000]", "cos1[dz:-500:5300]*sx", "sin2[dy:0:8000]*dx^2"]
)
def test_wave_names_round_trip(name):
    assert parse_term(name).name == name


@pytest.mark.parametrize(
    "bad", ["cos0[dx:0:8000]", "cos1[dx:8000:0]", "cos1[dx:a:b]", "tan1[dx:0:1]"]
)
def test_bad_wave_names_are_refused(bad):
    with pytest.raises(InputError):
        parse_term(bad)


def test_wave_derivatives_match_central_differences():
    terms = [parse_term(t) for t in ("cos3[dx:0:8000]*dy", "cos2[dz:0:4800]", "sx*dx", "dx^2*dz")]
    names = (*JOINTS, "sx")
    u = np.random.default_rng(0).uniform(0.0, 5000.0, (20, 4))
    h = 1e-2
    for k, joint in enumerate(JOINTS):
        e = np.zeros(4)
        e[k] = h
        fd = (design_matrix(u + e, names, terms) - design_matrix(u - e, names, terms)) / (2 * h)
        exact = design_matrix_derivative(u, names, terms, joint)
        np.testing.assert_allclose(exact, fd, rtol=1e-6, atol=1e-9)  # worst-case, relative


def test_a_wave_model_serialises_predicts_and_inverts():
    d, p = _data(1, wavy=True)
    model = fit_family(d, p, FAMILIES["quadratic+waves"], JOINTS, {}, RANGE_UM)
    assert any(
        not t.is_monomial for t, s in zip(model.terms, model.selected.any(0), strict=True) if s
    )
    again = KinematicModel.from_dict(model.to_dict())
    np.testing.assert_allclose(again.predict_um(d), model.predict_um(d), atol=1e-9)
    # Jacobian against central differences, max abs difference in µm/µm
    h = 1e-2
    fd = np.stack(
        [(model.predict_um(d[:10] + h * np.eye(3)[b]) - model.predict_um(d[:10] - h * np.eye(3)[b]))
         / (2 * h) for b in range(3)], axis=2,
    )  # fmt: skip
    assert np.abs(model.jacobian(d[:10]) - fd).max() < 1e-8
    limits = np.array([[-500.0, 8500.0], [-500.0, 8500.0], [-500.0, 5300.0]])
    solved = Compensator(model, limits).solve(model.predict_um(d[:20]))
    assert solved.converged.all()
    assert np.abs(solved.d_um - d[:20]).max() < 1e-6  # µm, worst joint
    np.testing.assert_allclose(model.p_base_um, model.predict_um(np.zeros(3))[0])


def test_held_out_choice_takes_waves_only_when_the_data_need_them():
    d, p = _data(2, wavy=True)
    choice = choose_family(d[:120], p[:120], JOINTS, {}, RANGE_UM)
    assert choice.family.name != "quadratic"
    assert choice.scores["quadratic"][0] > 1.3 * choice.scores[choice.family.name][0]
    d, p = _data(3, wavy=False)
    plain = choose_family(d[:120], p[:120], JOINTS, {}, RANGE_UM)
    assert plain.family.name == "quadratic"  # one-standard-error rule: the simplest that fits


def test_unknown_family_is_named():
    d, p = _data(4, wavy=False, n=60)
    with pytest.raises(InputError, match="family"):
        choose_family(d, p, JOINTS, {}, RANGE_UM, candidates=("quartic",))


@pytest.mark.slow
def test_smooth_fit_shrinks_noise_and_its_covariance_covers_the_truth():
    """Monte Carlo over 40 noise draws of one wavy truth: the penalised fit's 95 % region
    (chi-square, 3 degrees of freedom, the axes' predictions independent) holds the true
    position at 85-99 % of held-out points, and its RMS error at the travel's corners,
    where stepwise selection scatters most, is below the stepwise waves'."""
    rng = np.random.default_rng(7)
    d = rng.uniform(0.0, RANGE_UM[:, 1], (120, 3))
    grid = rng.uniform(0.0, RANGE_UM[:, 1], (50, 3))

    def true_p(x: np.ndarray) -> np.ndarray:
        p = x @ np.array([[1.0005, 0.002, 0.0], [-0.001, 0.9995, 0.003], [0.0, 0.001, 1.0002]]).T
        p = p + np.array([1000.0, 800.0, 300.0]) + 2e-7 * x[:, [2, 0, 1]] ** 2
        p[:, 1] += 1.5 * np.sin(x[:, 0] / 900.0)
        p[:, 2] += 1.0 * np.cos(x[:, 1] / 1100.0)
        return p

    corners = np.array(np.meshgrid(*RANGE_UM, indexing="ij")).reshape(3, -1).T  # (8, 3)
    inside, err_smooth, err_step = [], [], []
    for k in range(40):
        p = true_p(d) + np.random.default_rng(100 + k).normal(0.0, 0.3, (120, 3))
        smooth = fit_family(d, p, FAMILIES["smooth"], JOINTS, {}, RANGE_UM)
        step = fit_family(d, p, FAMILIES["quadratic+waves"], JOINTS, {}, RANGE_UM)
        e = true_p(grid) - smooth.predict_um(grid)
        var = smooth.prediction_std_um(grid) ** 2
        inside.append(np.mean(np.sum(e**2 / var, axis=1) <= 7.815))
        for model, errs in ((smooth, err_smooth), (step, err_step)):
            errs.append(np.sqrt(np.mean((true_p(corners) - model.predict_um(corners)) ** 2)))
    assert 0.85 <= np.mean(inside) <= 0.99
    assert np.mean(err_smooth) < np.mean(err_step)
    assert smooth.selection["method"] == "penalised"


def test_an_extra_input_that_cannot_be_identified_is_named_with_the_fix():
    from microcal.errors import DegenerateDataError
    from microcal.procedures.identification import identify

    d, p = _data(8, wavy=False, n=100)
    rng = np.random.default_rng(0)
    signs = {f"approach_{a}": rng.choice([-1.0, 1.0], 100) for a in "xyz"}
    assert identify(d, p, extra_inputs=signs).model.extra_inputs == ("sx", "sy", "sz")
    # every pose approached from below but two: the sign cannot be identified
    few = dict(signs, approach_x=np.where(np.arange(100) < 2, -1.0, 1.0))
    with pytest.raises(DegenerateDataError, match=r"approach_x takes one of its signs in only 2"):
        identify(d, p, extra_inputs=few)
    # a temperature that follows the x joint
    hot = {"temperature": 22.0 + d[:, 0] / 8000.0}
    with pytest.raises(DegenerateDataError, match=r"temperature follows the joints' positions"):
        identify(d, p, extra_inputs=hot)
