"""Validation (thesis 5.2.2): splits, k-fold cross-validation, and the simulator check."""

from __future__ import annotations

import numpy as np
import pytest

from microcal import InputError
from microcal.kinematics import (
    cross_validate,
    fit_matrix_model,
    fit_polynomial_model,
    kfold_indices,
    prediction_errors,
    validate_split,
)
from microcal.procedures.identification import default_train, identify
from microcal.sim.synthetic_run import synthetic_run


def test_kfold_covers_every_sample_once():
    folds = kfold_indices(170, 10, seed=3)
    allidx = np.concatenate(folds)
    assert sorted(allidx.tolist()) == list(range(170))
    assert {len(f) for f in folds} == {17}
    with pytest.raises(InputError, match="folds: expected between 2 and 5"):
        kfold_indices(5, 6)


def test_thesis_split_default():
    assert default_train(170) == 110
    assert default_train(100) == 65


def test_split_uses_the_first_poses_for_fitting():
    run = synthetic_run(170, seed=4)
    v = validate_split(fit_matrix_model, run.d_um, run.measured_um, 110)
    assert (v.n_fit, v.n_validate) == (110, 60)
    assert v.model.selection["n_samples"] == 110
    np.testing.assert_allclose(
        v.errors_um, prediction_errors(v.model, run.d_um[110:], run.measured_um[110:])
    )
    d = v.as_dict()
    assert set(d) >= {"n_fit", "n_validate", "mean_um", "std_um", "max_um", "rms_um", "p95_um"}


def test_cross_validation_repeats_the_selection_in_every_fold():
    run = synthetic_run(170, seed=5)
    cv = cross_validate(fit_polynomial_model, run.d_um, run.measured_um, k=10, seed=1)
    assert cv.errors_um.shape == (170,)
    assert cv.term_frequency.shape == (3, 10)
    assert np.all(cv.term_frequency[:, -1] == 1.0)  # the constant is always in
    names = list(cv.term_names)
    assert cv.term_frequency[2, names.index("dz^2")] == 1.0  # z always bends


def thesis_simulator_table(seed: int) -> dict[str, float]:
    """Mean validation prediction errors (µm) of both models and of the oracle."""
    run = synthetic_run(170, seed=seed)
    matrix = identify(run.d_um, run.measured_um, "matrix")
    poly = identify(run.d_um, run.measured_um, "polynomial")
    # The oracle: the simulator's true kinematics (hysteresis included) predicting the same
    # noisy measurements; its error is the measurement noise alone.
    oracle = np.linalg.norm(run.measured_um[110:] - run.true_um[110:], axis=1)
    return {
        "matrix": float(matrix.validation["mean_um"]),
        "polynomial": float(poly.validation["mean_um"]),
        "oracle": float(oracle.mean()),
    }


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_thesis_simulator_polynomial_within_20_percent_of_the_oracle(seed):
    t = thesis_simulator_table(seed)
    # Metric: mean Eq 5.1 error over the 60 validation poses, relative to the oracle's.
    assert t["polynomial"] == pytest.approx(t["oracle"], rel=0.20)
    assert t["matrix"] > t["polynomial"]
