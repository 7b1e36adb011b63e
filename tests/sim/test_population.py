"""The population preset: another platform per seed, joint errors no quadratic fits, the
truth's inversion and its logarithmic creep."""

from __future__ import annotations

import numpy as np
import pytest

from microcal.kinematics.families import FAMILIES, fit_family
from microcal.kinematics.terms import JOINTS
from microcal.sim import platform
from microcal.sim.population import draw_population

TRAVEL = np.array([[0.0, 8000.0], [0.0, 8000.0], [0.0, 4800.0]])


def test_each_seed_is_another_platform_and_the_same_seed_the_same():
    d = np.random.default_rng(0).uniform(0.0, TRAVEL[:, 1], (50, 3))
    a = draw_population(1).truth.position_um(d)
    np.testing.assert_array_equal(a, draw_population(1).truth.position_um(d))
    b = draw_population(2).truth.position_um(d)
    assert np.abs(a - b).max() > 5.0  # µm: different manipulators
    # the thesis preset is untouched by the population's draws
    thesis = platform("thesis", 0).manipulator.truth
    assert thesis.joint_errors is None
    assert thesis.creep_law == "exp"


def test_the_joint_errors_leave_what_no_quadratic_fits():
    truth = draw_population(3).truth
    d = np.random.default_rng(1).uniform(0.0, TRAVEL[:, 1], (400, 3))
    p = truth.position_um(d)  # noise-free: all that is left is lack of fit
    quad = fit_family(d, p, FAMILIES["quadratic"], JOINTS, {}, TRAVEL)
    waves = fit_family(d, p, FAMILIES["cubic+waves"], JOINTS, {}, TRAVEL)
    rms = [np.sqrt(np.mean((m.predict_um(d) - p) ** 2)) for m in (quad, waves)]
    assert rms[0] > 0.3  # µm RMS per coordinate that the quadratic misses
    assert rms[1] < 0.5 * rms[0]  # the waves follow most of it


def test_truth_inverts_exactly_and_creep_is_logarithmic():
    truth = draw_population(4).truth
    target = truth.position_um(np.array([[4000.0, 3000.0, 2000.0]]), np.ones((1, 3)), 22.3)
    d = truth.solve_um(target, np.ones((1, 3)), 22.3)
    np.testing.assert_allclose(d, [[4000.0, 3000.0, 2000.0]], atol=1e-6)
    left = truth.creep_um(np.array([[100.0, 0, 0]]), np.array([0.0, 1.0, 5.0, 1e4]))[:, 0]
    assert np.all(np.diff(left) > 0)  # decays, never overshoots
    assert left[-1] == 0.0  # to nothing


def test_each_population_seed_is_another_unit_and_its_calibration_is_refused_on_another():
    """A seed of ``population`` is another manipulator: its identity says which, so that a
    calibration made on one seed is refused on another (the thesis preset's kinematics are the
    same for every seed, and so is its identity)."""
    from microcal.errors import InputError
    from microcal.kinematics.manipulator_calibration import ManipulatorCalibration
    from microcal.kinematics.models import fit_matrix_model

    a = platform("population", seed=3).manipulator.identity
    b = platform("population", seed=4).manipulator.identity
    assert a == "simulated m1 (population seed 3)"
    assert a != b
    assert platform("thesis", seed=3).manipulator.identity == "simulated m1"
    d = np.random.default_rng(0).uniform(0, 8000, (20, 3))
    figures = {"n_fit": 20, "n_validate": 0, "mean_um": 0.1, "std_um": 0.1, "max_um": 0.2,
               "rms_um": 0.1}  # fmt: skip
    entry = ManipulatorCalibration("m1", fit_matrix_model(d, d), figures, {"device": a})
    entry.check_device(a)
    with pytest.raises(
        InputError, match=r"calibrated on simulated m1 \(population seed 3\)"
    ) as err:
        entry.check_device(b)
    assert "unless its --rig names a rig file" in str(err.value)  # the default is the simulator
